"""The stand, its setup costs and the design space: what a plan may vary and what it costs.

:class:`Stand` is the test stand and system (latitude, base tilt, heading noise);
:class:`Costs` the time of warm-up and of every setup change; :class:`DesignSpace` the factors
a plan may vary, whose every combination is a candidate run (:class:`Candidates`).
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from .. import units
from ..data import DEFAULT_MIN_RATE_DPS
from ..information import DEFAULT_ARW, heading_sigma

#: the alignments' sampling period, s (500 Hz, the paper's)
SAMPLE_PERIOD = 0.002


def positive(name, value, allow_zero=False):
    v = float(value)
    if not np.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        raise ValueError(f"{name} = {value!r} is not allowed; allowed: a finite number "
                         f"{'>= 0' if allow_zero else '> 0'}")
    return v


@dataclass(frozen=True)
class Costs:
    """Stand-time costs of a plan, s.

    Attributes
    ----------
    warmup : float
        Before the first run (power-on to thermal steady state).
    azimuth_change : float
        Turning the stand to another azimuth (and settling).
    rate_change : float
        Changing the table rate or its sense.
    tilt_change : float
        Resetting the tilt fixture.
    run_overhead : float
        Per alignment beyond its duration (data saving, restart).
    """

    warmup: float = 3600.0
    azimuth_change: float = 600.0
    rate_change: float = 60.0
    tilt_change: float = 1200.0
    run_overhead: float = 0.0

    def __post_init__(self):
        for name in ("warmup", "azimuth_change", "rate_change", "tilt_change", "run_overhead"):
            object.__setattr__(self, name, positive(f"costs.{name} (s)", getattr(self, name), True))

    def setups(self, rate, azimuth, tilt_x, tilt_y):
        """Setup time before each run (s, shape (n,); the first is the warm-up)."""
        rate, azimuth = np.asarray(rate, float), np.asarray(azimuth, float)
        out = np.zeros(rate.size)
        if rate.size == 0:
            return out
        out[0] = self.warmup
        d_az = np.abs(np.angle(np.exp(1j * np.diff(azimuth)))) > 1e-9
        d_tilt = (np.abs(np.diff(tilt_x)) > 1e-12) | (np.abs(np.diff(tilt_y)) > 1e-12)
        d_rate = np.abs(np.diff(rate)) > 1e-12
        out[1:] = self.azimuth_change * d_az + self.tilt_change * d_tilt + self.rate_change * d_rate
        return out

    def schedule(self, rate, azimuth, tilt_x, tilt_y, duration, not_before=None):
        """Start times since power-on (s, shape (n,)) of runs done in this order, each
        waiting, where given, until ``not_before`` (s)."""
        setup = self.setups(rate, azimuth, tilt_x, tilt_y)
        busy = np.concatenate([[0.0], np.asarray(duration, float)[:-1] + self.run_overhead])
        if not_before is None:
            return np.cumsum(setup + busy)
        t = np.empty(setup.size)
        prev = 0.0
        for i in range(setup.size):
            prev = t[i] = max(prev + busy[i] + setup[i], not_before[i])
        return t


@dataclass(frozen=True)
class Stand:
    """The test stand and system as the design sees them.

    Attributes
    ----------
    latitude : float
        rad (default 28.07 deg, the paper's 0.49 rad).
    tilt : tuple of 2 float
        Tilt of the turntable base on the stand, fixed in b0: ``(x, y)`` = (roll, pitch), rad,
        as the leveling measures it; a plan's ``tilt_x, tilt_y`` add to it. Default: the
        default simulated system's (-55, -120) arcsec.
    arw : float
        Gyro angle random walk, rad/sqrt(s) (heading noise model,
        :func:`~hse_opt.information.heading_sigma`).
    floor : float
        Run-to-run heading scatter beyond the noise, rad.
    """

    latitude: float = 28.07 * units.DEG
    tilt: tuple = (-55.0 * units.ARCSEC, -120.0 * units.ARCSEC)
    arw: float = DEFAULT_ARW
    floor: float = 0.0

    def __post_init__(self):
        tilt = tuple(float(v) for v in self.tilt)
        if len(tilt) != 2 or not all(np.isfinite(tilt)):
            raise ValueError(f"stand tilt = {self.tilt!r}; allowed: two finite angles (x roll, y pitch), rad")
        object.__setattr__(self, "tilt", tilt)
        if not abs(self.latitude) < np.pi / 2:
            raise ValueError(f"stand latitude = {self.latitude!r} rad; allowed: |latitude| < 90 deg")
        positive("stand arw", self.arw, True)
        positive("stand floor", self.floor, True)

    def sigma(self, duration):
        """1-sigma heading error of alignments of these durations, rad."""
        return heading_sigma(duration, self.latitude, self.arw, self.floor)

    def inputs(self, mm, rate, azimuth, tilt_x, tilt_y, duration, t_start):
        """Measurement-model inputs (n_x, n) of runs on this stand (SI arrays)."""
        n = np.size(rate)
        tilt_x = np.broadcast_to(np.asarray(tilt_x, float), (n,))
        tilt_y = np.broadcast_to(np.asarray(tilt_y, float), (n,))
        return mm.inputs(rate, azimuth, self.latitude, duration, t_start,
                         pitch=self.tilt[1] + tilt_y, roll=self.tilt[0] + tilt_x)


@dataclass(frozen=True)
class Candidates:
    """Candidate run settings (SI arrays of one length): ``rate`` (signed, rad/s),
    ``azimuth`` (rad), ``tilt_x``, ``tilt_y`` (fixture tilt, rad), ``duration`` (s) and the
    nominal ``t_start`` (s since power-on: the middle of the run's time slot) and
    ``not_before`` (s: the start of the slot, before which the run waits)."""

    rate: np.ndarray
    azimuth: np.ndarray
    tilt_x: np.ndarray
    tilt_y: np.ndarray
    duration: np.ndarray
    t_start: np.ndarray
    not_before: np.ndarray

    def __len__(self):
        return int(self.rate.size)

    def take(self, idx):
        return Candidates(*(getattr(self, f)[idx] for f in self._fields()))

    def replace(self, **kw):
        return Candidates(**{f: np.asarray(kw.get(f, getattr(self, f)), float) for f in self._fields()})

    def inputs(self, mm, stand):
        """Measurement-model inputs (n_x, n) on ``stand``."""
        return stand.inputs(mm, self.rate, self.azimuth, self.tilt_x, self.tilt_y, self.duration, self.t_start)

    def rank(self):
        """Canonical rank of each candidate (int, 0 ... n-1): the settings in lexicographic
        order -- time slot, tilt, azimuth in [0, 2 pi), rate, duration -- so that ties between
        candidates are broken the same way whatever order they are listed in."""
        keys = (np.round(self.duration, 6), np.round(self.rate, 12),
                np.round(np.mod(np.round(self.azimuth, 12), np.round(2 * np.pi, 12)), 12),
                np.round(self.tilt_y, 12), np.round(self.tilt_x, 12), np.round(self.not_before, 6))
        out = np.empty(len(self), int)
        out[np.lexsort(keys)] = np.arange(len(self))
        return out

    def positions(self):
        """Stand position of each candidate (int labels in the settings' order): time slot,
        tilt and azimuth -- what costs a setup or a wait to change; rate and duration do not."""
        keys = np.column_stack([self.not_before, self.tilt_x, self.tilt_y, np.mod(self.azimuth, 2 * np.pi)])
        return np.unique(keys.round(9), axis=0, return_inverse=True)[1].ravel()

    @property
    def slot(self):
        """Time-slot label of each candidate (int, in time order)."""
        return np.unique(np.round(self.not_before, 6), return_inverse=True)[1].ravel()

    @staticmethod
    def _fields():
        return ("rate", "azimuth", "tilt_x", "tilt_y", "duration", "t_start", "not_before")


@dataclass(frozen=True)
class DesignSpace:
    """What a plan may vary.

    Attributes
    ----------
    rates : tuple of 2 float
        Limits of the bias rate's magnitude |Omega|, rad/s (default 20-60 deg/s).
    n_rates : int
        Rate levels between the limits (candidates; refinement moves off them).
    reverse : bool
        Both rotation senses; else only ``sense``.
    sense : int
        +1 or -1, the sense used when ``reverse`` is False.
    azimuths : tuple of float, optional
        Allowed stand azimuths, rad; default every ``azimuth_step`` round the circle.
    azimuth_step : float
        rad (default 15 deg).
    max_tilt : float
        Tilt-fixture limit, rad (0: no fixture); fixture settings are no tilt and the limit
        in ``n_tilt_directions`` directions.
    n_tilt_directions : int
    durations : tuple of float
        Allowed alignment durations, s (default 600 s, the paper's 10 minutes).
    time_slots : int
        Time since power-on as a factor: the test time is cut into this many slots, the
        approximate design spends at most its share of the budget in each, and the runs follow
        slot by slot. Needed for effects that depend on time (``warmup``); with 1 every
        candidate is seen at the middle of the test.
    min_rate : float
        Lock-in limit, rad/s (default :data:`hse_opt.data.DEFAULT_MIN_RATE_DPS`): the rate
        limits may not go below it (a plan's loader rejects such rates).

    Every duration must cover one table revolution at the lowest rate plus one sample
    (:data:`SAMPLE_PERIOD`), as an alignment needs, and at most a day.
    """

    rates: tuple = (20.0 * units.DEG_PER_S, 60.0 * units.DEG_PER_S)
    n_rates: int = 5
    reverse: bool = False
    sense: int = 1
    azimuths: tuple | None = None
    azimuth_step: float = 15.0 * units.DEG
    max_tilt: float = 0.0
    n_tilt_directions: int = 8
    durations: tuple = (600.0,)
    time_slots: int = 1
    min_rate: float = DEFAULT_MIN_RATE_DPS * units.DEG_PER_S

    def __post_init__(self):
        lo, hi = (float(v) for v in self.rates)
        if not (np.isfinite(self.min_rate) and self.min_rate >= 0):
            raise ValueError(f"min_rate = {self.min_rate!r} rad/s; allowed: a finite number >= 0")
        if lo < self.min_rate * (1 - 1e-12):
            raise ValueError(f"rate limit {lo / units.DEG_PER_S:g} deg/s is inside the lock-in limit; allowed: "
                             f">= {self.min_rate / units.DEG_PER_S:g} deg/s (min_rate, --min-rate-dps)")
        if not (np.isfinite(lo) and np.isfinite(hi) and 0 < lo <= hi):
            raise ValueError(f"rate limits {self.rates!r} rad/s; allowed: 0 < low <= high")
        if hi > 400 * units.DEG_PER_S:
            raise ValueError(f"rate limit {hi / units.DEG_PER_S:g} deg/s is not allowed; allowed: <= 400 deg/s "
                             "(rates are rad/s inside: was a deg/s value passed?)")
        object.__setattr__(self, "rates", (lo, hi))
        if int(self.n_rates) < 1:
            raise ValueError(f"n_rates = {self.n_rates!r}; allowed: an integer >= 1")
        object.__setattr__(self, "n_rates", 1 if lo == hi else int(self.n_rates))
        if self.sense not in (1, -1):
            raise ValueError(f"sense = {self.sense!r}; allowed: +1 or -1")
        if self.azimuths is not None:
            az = tuple(float(a) for a in np.atleast_1d(self.azimuths))
            if not az or not all(np.isfinite(az)):
                raise ValueError("azimuths: allowed a non-empty list of finite angles, rad")
            object.__setattr__(self, "azimuths", az)
        elif not 0 < self.azimuth_step <= 2 * np.pi:
            raise ValueError(f"azimuth_step = {self.azimuth_step!r} rad; allowed: 0 < step <= 2 pi")
        positive("max_tilt (rad)", self.max_tilt, True)
        if self.max_tilt > 1.0 * units.DEG:
            raise ValueError(f"max_tilt = {self.max_tilt / units.ARCSEC:g} arcsec is not allowed; allowed: "
                             f"<= 3600 arcsec (the model is first order in the tilt)")
        if int(self.n_tilt_directions) < 1:
            raise ValueError(f"n_tilt_directions = {self.n_tilt_directions!r}; allowed: an integer >= 1")
        d = tuple(float(v) for v in np.atleast_1d(self.durations))
        if not d or not all(np.isfinite(d)) or min(d) <= 0:
            raise ValueError(f"durations = {self.durations!r}; allowed: positive seconds")
        shortest = 2 * np.pi / lo + SAMPLE_PERIOD
        if min(d) < shortest or max(d) > 86400.0:
            raise ValueError(f"duration {min(d) if min(d) < shortest else max(d):g} s is not allowed; allowed: "
                             f"{shortest:.6g} s (one table revolution at the lowest rate, "
                             f"{lo / units.DEG_PER_S:g} deg/s, plus one sample) to 86400 s")
        object.__setattr__(self, "durations", d)
        if isinstance(self.time_slots, bool) or int(self.time_slots) != self.time_slots or self.time_slots < 1:
            raise ValueError(f"time_slots = {self.time_slots!r}; allowed: an integer >= 1")

    @property
    def azimuth_grid(self):
        if self.azimuths is not None:
            return np.array(self.azimuths)
        n = max(1, int(round(2 * np.pi / self.azimuth_step)))
        return np.arange(n) * (2 * np.pi / n)

    @property
    def azimuth_spacing(self):
        """Half-width of the refinement's azimuth window, rad."""
        g = np.sort(np.mod(self.azimuth_grid, 2 * np.pi))
        if g.size < 2:
            return 0.0
        return float(np.max(np.diff(np.concatenate([g, [g[0] + 2 * np.pi]]))))

    def candidates(self, warmup=0.0, test_time=0.0):
        """Every combination of the factors (:class:`Candidates`); a run of slot k of the
        ``test_time`` after the ``warmup`` (s) is seen at the slot's middle and does not start
        before the slot does."""
        lo, hi = self.rates
        mags = np.linspace(lo, hi, self.n_rates)
        rates = np.concatenate([mags, -mags]) if self.reverse else self.sense * mags
        tilts = [(0.0, 0.0)]
        if self.max_tilt > 0:
            ang = np.arange(self.n_tilt_directions) * 2 * np.pi / self.n_tilt_directions
            tilts += [(self.max_tilt * np.cos(a), self.max_tilt * np.sin(a)) for a in ang]
        slots = range(int(self.time_slots))
        g = np.array(list(itertools.product(slots, rates, self.azimuth_grid, range(len(tilts)),
                                            self.durations)), dtype=float)
        t = np.array(tilts)[g[:, 3].astype(int)]
        start = warmup + g[:, 0] * test_time / self.time_slots
        centre = start + 0.5 * test_time / self.time_slots
        return Candidates(g[:, 1], g[:, 2], t[:, 0], t[:, 1], g[:, 4], np.maximum(start, centre - g[:, 4] / 2),
                          start)



@dataclass(frozen=True)
class Resolution:
    """The settings a stand can set: the final plan is rounded to these steps and re-certified.

    Attributes
    ----------
    rate : float
        rad/s (default 0.1 deg/s).
    azimuth : float
        rad (default 0.01 deg).
    tilt : float
        Tilt-fixture step, rad (default 1 arcsec; rounded towards zero, inside the fixture's limit).
    """

    rate: float = 0.1 * units.DEG_PER_S
    azimuth: float = 0.01 * units.DEG
    tilt: float = 1.0 * units.ARCSEC

    def __post_init__(self):
        for name in ("rate", "azimuth", "tilt"):
            object.__setattr__(self, name, positive(f"resolution.{name}", getattr(self, name)))
