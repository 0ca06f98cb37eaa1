"""The plausible range of each catalogue parameter: the values it takes on a navigation-grade
rotating RLG system and its test stand. The diagnosis judges fitted magnitudes against them
(:mod:`hse_opt.diagnose.plausibility`); the alias budget (:mod:`hse_opt.aliasing`) puts each
effect missing from a model at the edge of its range.

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
