"""Monte Carlo validation of a plan: simulate it many times with the numeric simulator, fit every
replicate and compare the empirical scatter of each estimate with the design's prediction.

Validation sits above design and sim: the design package never imports the simulator.
"""
from __future__ import annotations

import sys
from dataclasses import dataclass

import numpy as np

from ..design import Stand, evaluate
from ..fit import as_model, fit
from ..model.composition import Model


@dataclass(frozen=True)
class MonteCarloResult:
    """Empirical against predicted scatter of the estimates of a simulated plan.

    Attributes
    ----------
    names, units : tuple of str
    predicted_std : numpy.ndarray, shape (n_p,)
        The design's prediction (its heading-noise model), display units.
    empirical_std, mean : numpy.ndarray, shape (n_p,)
        Scatter and mean of the replicates' estimates, display units.
    run_scatter_ratio : float
        The simulated alignments' own heading scatter (each run of the plan across the
        replicates, pooled) over the noise model's sigma: how far the noise model is off.
    estimates : numpy.ndarray, shape (n_rep, n_p)
    n_rep : int
    """

    names: tuple
    units: tuple
    predicted_std: np.ndarray
    empirical_std: np.ndarray
    mean: np.ndarray
    run_scatter_ratio: float
    estimates: np.ndarray
    n_rep: int

    @property
    def ratio(self):
        """Empirical / predicted sigma of each parameter."""
        return self.empirical_std / self.predicted_std

    @property
    def propagated_std(self):
        """The prediction with the noise model scaled to the simulated alignments' scatter:
        what the design's information propagation predicts from the real run noise."""
        return self.predicted_std * self.run_scatter_ratio

    def to_dict(self):
        return {"n_rep": self.n_rep, "run_scatter_ratio": self.run_scatter_ratio, "parameters": {
            n: {"predicted_std": float(p), "empirical_std": float(e), "ratio": float(e / p),
                "propagated_std": float(p * self.run_scatter_ratio), "mean": float(m), "unit": u}
            for n, u, p, e, m in zip(self.names, self.units, self.predicted_std, self.empirical_std,
                                     self.mean)}}


def monte_carlo(plan, model=None, n_rep=100, *, truth=None, seed=0, jobs=1, tilt_known=True, progress=True,
                client=None):
    """Simulate ``plan`` ``n_rep`` times, fit each replicate, compare the scatter of the
    estimates with the prediction.

    The prediction is :func:`evaluate` on the stand of the simulated system (latitude, base
    tilt, gyro ARW). Replicate ``r`` uses run ids ``r n + 1 ... r n + n`` and so its own
    random numbers (:func:`hse_opt.sim.run_campaign` seeds each run by its id); every
    replicate has the plan's start times.

    Parameters
    ----------
    plan : hse_opt.data.Plan
    model : Model, str, sequence of str, or a list of models
        A list of :class:`~hse_opt.model.Model` (or ``"a,b"`` strings) fits every replicate
        with each and returns one result per model.
    n_rep : int
        Replicates, >= 2.
    truth : hse_opt.sim.TruthConfig, optional
        Default: the default simulated system.
    seed : int
    jobs : int
        Worker processes of the campaign runner.
    tilt_known : bool
    progress : bool
        A tqdm bar on stderr.
    client : dask.distributed.Client, optional

    Returns
    -------
    MonteCarloResult, or a tuple of them for a list of models
    """
    from ..sim import TruthConfig, run_campaign

    if isinstance(n_rep, bool) or int(n_rep) != n_rep or n_rep < 2:
        raise ValueError(f"n_rep = {n_rep!r}; allowed: an integer >= 2")
    n_rep = int(n_rep)
    several = isinstance(model, list) and all(isinstance(m, (Model, str)) for m in model)
    models = [as_model(m) for m in model] if several else [as_model(model)]
    truth = truth or TruthConfig.default()
    if any(v != 0 for v in truth.stand.tilt):
        raise ValueError("truth stand.tilt_arcsec (a tilt fixed in n) is not in the design's Stand model; "
                         "allowed: [0, 0] (the base tilt is stand.mount_tilt_arcsec)")
    # the truth's white heading noise: the gyros' own ARW and the pulse quantization (the
    # counters' remainder, dithered by the table jitter: q |Omega| sqrt(dt / 12)) at the plan's
    # RMS rate, in quadrature (studies/simulator_noise.py)
    rms_rate = float(np.sqrt(np.mean(np.square(plan.rate))))
    n_quant = truth.gyro.pulse * rms_rate * np.sqrt(truth.timing.sample_period / 12.0)
    stand = Stand(latitude=truth.site.latitude, tilt=tuple(truth.stand.mount_tilt),
                  arw=float(np.hypot(truth.gyro.arw, n_quant)))
    preds = [evaluate(plan, m, stand=stand, tilt_known=tilt_known) for m in models]
    cols, n = plan.to_columns(), plan.run.size
    rows = [{k: (r * n + i + 1 if k == "run" else float(v[i])) for k, v in cols.items()}
            for r in range(n_rep) for i in range(n)]
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=len(rows), unit="run", file=sys.stderr, desc="monte carlo")
    try:
        out = run_campaign(rows, truth, seed, jobs=jobs, client=client,
                           progress=None if bar is None else (lambda done, total: bar.update(done - bar.n)))
    finally:
        if bar is not None:
            bar.close()
    replicates = [out.subset(np.arange(r * n, (r + 1) * n)).replace(source=f"replicate {r}")
                  for r in range(n_rep)]
    # every replicate repeats each run's deterministic errors: the scatter across them is noise
    h = np.asarray(out.heading_err).reshape(n_rep, n)
    ratio = float(np.sqrt(np.mean(h.var(axis=0, ddof=1) / stand.sigma(plan.duration) ** 2)))
    results = []
    for m, pred in zip(models, preds):
        est = np.empty((n_rep, len(pred.names)))
        for r, runs in enumerate(replicates):
            res = fit(runs, m, tilt_known=tilt_known)
            est[r] = [res.values[res.names.index(nm)] for nm in pred.names]
        results.append(MonteCarloResult(pred.names, pred.units, pred.std, est.std(axis=0, ddof=1),
                                        est.mean(axis=0), ratio, est, n_rep))
    return tuple(results) if several else results[0]

