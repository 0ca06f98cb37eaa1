"""The raw-log quality checks' records (:func:`hse_opt.align.quality.assess`): their
thresholds, each finding, and the result (the log to align and what was found). The module
docstring of :mod:`hse_opt.align.quality` gives each threshold's physical reason.

Units: SI (rad, m/s, s, degC).
"""
from __future__ import annotations

from dataclasses import dataclass

from hse_opt import units

__all__ = ["Thresholds", "Finding", "LogRefused", "Quality"]


@dataclass(frozen=True)
class Thresholds:
    """The checks' thresholds (SI); :mod:`hse_opt.align.quality`'s module docstring gives each
    one's physical reason.

    Attributes
    ----------
    encoder_sigmas : float
        An encoder step is off beyond this many robust 1-sigma of the steps.
    encoder_floor : float
        ... and beyond this, rad (2 arcsec).
    repair_samples : int
        At most this many consecutive bad encoder samples are repaired.
    window_s : float
        Window of the rate and channel checks, s.
    rate_ripple : float
        Allowed relative deviation of a window's table rate from the median rate ...
    rate_sigmas : float
        ... plus this many robust 1-sigma of the windows' own noise.
    stall : float
        A window rate below this fraction of the median rate is a stall.
    channel_sigmas : float
        A channel's window residual is a fault beyond this many robust 1-sigma.
    gyro_floor, accel_floor : float
        ... and beyond these, rad and m/s per window.
    norm_floor : float
        A window's gyro turn over the encoder's, or its specific force, relative to the
        median: a fault beyond ``channel_sigmas`` robust 1-sigma and this.
    gyro_scale : float
        The gyros' turn over the encoder's must lie within ``1 +- gyro_scale``.
    gravity : (float, float)
        The accelerometers' specific force must lie in this band, m/s^2.
    stuck_samples : int
        A channel repeating one value this many samples in a bad window is stuck (when the
        run explains the window's residual).
    saturated_samples : int
        A channel holding its extreme value this many consecutive samples, beyond the range
        a static base allows, is saturated.
    false_alarm : float
        The window tests' false-alarm probability per clean log (Bonferroni over the log's
        windows and channels); ``channel_sigmas`` and ``rate_sigmas`` are raised to its level
        when that is higher (the Bonferroni level of :mod:`hse_opt.align.quality`).
    temp_drift_c : float
        A temperature drift above this over the run is noted, degC.
    step_span_s : float
        The gyro step test compares the mean angle residual over this span after each
        sample with that over the span before, s (check 3b, :mod:`hse_opt.align.steps`).
    """

    encoder_sigmas: float = 10.0
    encoder_floor: float = 2.0 * units.ARCSEC
    repair_samples: int = 3
    window_s: float = 0.512
    rate_ripple: float = 5e-3
    rate_sigmas: float = 5.0
    stall: float = 0.5
    channel_sigmas: float = 10.0
    gyro_floor: float = 1e-3 * units.ARCSEC
    accel_floor: float = 1e-7
    norm_floor: float = 1e-6
    gyro_scale: float = 5e-3
    gravity: tuple = (9.7, 9.9)
    stuck_samples: int = 25
    saturated_samples: int = 3
    false_alarm: float = 1e-4
    temp_drift_c: float = 1.0
    step_span_s: float = 0.25


#: the default thresholds (immutable)
_THRESHOLDS = Thresholds()


@dataclass(frozen=True)
class Finding:
    """One finding of :func:`~hse_opt.align.quality.assess`.

    Attributes
    ----------
    check : str
        ``encoder``, ``rate``, ``channel``, ``temperature`` or ``metadata``.
    sample : int or None
        Sample index (None for metadata).
    time : float or None
        The sample's timestamp, s (``t_s``).
    action : str
        ``repaired``, ``refused`` or ``noted``.
    detail : str
        What was found, in display units, and for a refusal what is allowed.
    """

    check: str
    sample: int | None
    time: float | None
    action: str
    detail: str

    def text(self):
        """One line: ``<check> at sample k (t = ... s): <detail>``."""
        where = "" if self.sample is None else f" at sample {self.sample} (t = {self.time:.6g} s)"
        return f"{self.check}{where}: {self.detail}"


class LogRefused(ValueError):
    """A log the quality checks refuse; the message is the first refusal (file, sample, time)."""


@dataclass(frozen=True, eq=False)
class Quality:
    """Result of :func:`~hse_opt.align.quality.assess`.

    Attributes
    ----------
    log : RawLog
        The log to align: repaired where a rule applied, else the input itself.
    findings : tuple of Finding
    """

    log: object
    findings: tuple = ()

    @property
    def refused(self):
        """True when a finding refuses the log."""
        return any(f.action == "refused" for f in self.findings)

    @property
    def repaired(self):
        """True when the returned log differs from the input."""
        return any(f.action == "repaired" for f in self.findings)

    def summary(self):
        """The RUNS.csv ``quality`` text: ``ok``, or ``repaired: ...; noted: ...``."""
        parts = [f"{f.action}: {f.text()}" for f in self.findings]
        return "; ".join(parts) if parts else "ok"

    def raise_if_refused(self, source):
        """Raise :class:`LogRefused` naming ``source`` and the first refusal (with a count
        of the others)."""
        refusals = [f for f in self.findings if f.action == "refused"]
        if refusals:
            more = f" (and {len(refusals) - 1} more)" if len(refusals) > 1 else ""
            raise LogRefused(f"{source}: {refusals[0].text()}{more}")
