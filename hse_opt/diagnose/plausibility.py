"""Physical plausibility of fitted magnitudes: the range each catalogue parameter takes on a
navigation-grade rotating RLG system and its test stand. A candidate whose fit needs a value
beyond its range explains the data only with an implausible magnitude; the diagnosis says so
beside the ranking (it does not change the statistics).

Ranges (display units) and where they come from:

``lambda2`` |.| <= 60 arcsec
    K_g non-orthogonality drift between calibrations: the paper (Yu et al. 2013, Table 1 and
    Sec. 4) fits a few arcsec; tens of arcsec would be a failed system calibration.
``bias_z`` |.| <= 0.05 deg/h
    residual RLG bias along the rotation axis: navigation-grade ring-laser gyros have bias
    stabilities of 0.001-0.01 deg/h (Titterton & Weston, *Strapdown Inertial Navigation
    Technology*, 2nd ed., Table 4.1 / Sec. 6.3), a residual up to a few times that.
``delay`` |.| <= 500 us
    gyro-encoder time offset of the data acquisition: sampling and interface latencies of tens
    to a few hundred microseconds (Zhang, Wu, Jiang 2011, J. NUDT 33(1):105-108, cited by the
    paper, on the turntable's angle timing in a rate-biased RLG north-finder).
``sf_nonlin`` |.| <= 0.2 ppm/(deg/s)
    RLG scale-factor nonlinearity of 1-10 ppm over the rate range (Titterton & Weston, Table
    4.1), i.e. up to ~0.2 ppm per deg/s at the 40-60 deg/s bias rates of the paper's system.
``enc_c1 enc_s1 enc_c2 enc_s2`` |.| <= 30 arcsec
    periodic error of the table's angle encoder: precision optical encoders are specified at
    +-1 to +-10 arcsec (manufacturers' data sheets for 20-27 bit rotary encoders; Zhang, Wu,
    Jiang 2011 study periodic errors of this order in the same system class).
``warmup_amp`` |.| <= 60 arcsec, ``warmup_tau`` 60 s .. 3 h
    thermal mount rotation after power-on: tens of arcsec settling over tens of minutes
    (Titterton & Weston, Sec. 6.3 on warm-up effects of RLG systems).
``az_c2 az_s2`` |.| <= 20 arcsec
    periodic reading error of a surveyed test stand (theodolite / indexing-table references
    are a few arcsec).
"""
from __future__ import annotations

import math

#: name -> (lower, upper) in the parameter's display unit
RANGES = {
    "lambda2": (-60.0, 60.0),
    "bias_z": (-0.05, 0.05),
    "delay": (-500.0, 500.0),
    "sf_nonlin": (-0.2, 0.2),
    "enc_c1": (-30.0, 30.0), "enc_s1": (-30.0, 30.0), "enc_c2": (-30.0, 30.0), "enc_s2": (-30.0, 30.0),
    "warmup_amp": (-60.0, 60.0),
    "warmup_tau": (60.0, 10800.0),
    "az_c2": (-20.0, 20.0), "az_s2": (-20.0, 20.0),
}


def judge(fit_result, base=None):
    """Sentences on ``fit_result``'s parameters beyond their plausible range, and on the
    base model's parameters that the candidate moves by more than 3 sigma (``base``: the base
    model's FitResult). Empty when every magnitude is plausible."""
    out = []
    for name, value, std, unit in zip(fit_result.names, fit_result.values, fit_result.std, fit_result.units):
        lo, hi = RANGES.get(_key(name), (-math.inf, math.inf))
        if not lo <= value <= hi:
            out.append(f"{name} = {value:.3g} {unit} is outside its plausible range [{lo:g}, {hi:g}] {unit}")
    if base is not None:
        for name, v0, s0 in zip(base.names, base.values, base.std):
            if name in fit_result.names and s0 > 0:
                v1 = fit_result.value(name)[0]
                if abs(v1 - v0) > 3 * s0:
                    out.append(f"moves {name} from {v0:.3g} to {v1:.3g} ({abs(v1 - v0) / s0:.1f} sigma)")
    return tuple(out)


def _key(name):
    """``bias_z*tilt_cos`` (a tilt-coupled coefficient when the tilt is unknown) has no range of
    its own: only plain parameter names are judged."""
    return name if "*" not in name else ""
