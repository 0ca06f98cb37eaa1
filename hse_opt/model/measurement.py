"""The heading-level measurement model h(params; run) and its Jacobian.

A :class:`~hse_opt.model.composition.Model` (a set of effects) gives, for a set of runs, a
:class:`MeasurementModel`: CasADi Functions ``h(p, x)`` (heading error of one run,
rad, estimated - true, as the alignment processor forms it: the full nonlinear gyrocompass,
:func:`~hse_opt.model.symbolic.heading_error_alignment`) and ``J(p, x) = dh/dp``, built
once and batch-evaluated over runs with ``Function.map``.

Run inputs ``x`` (SI), one column per run, read through the named view
:class:`~hse_opt.model.inputs.RunInputs`: rate (rad/s, signed), azimuth (rad), pitch and roll
of b0 (rad), latitude (rad), t_start (s since power-on), duration (s), then the covariates the
model's effects use.

Runs without pitch/roll (tilt unknown): the tilt is not a run input. Every parameter whose
heading signature couples through the tilt (lambda2, the axis bias, the scale-factor
nonlinearity) is replaced by free coefficients ``<name>*tilt_cos``, ``<name>*tilt_sin``,
``<name>*tilt_const``: the products of the parameter with the rotation axis's east
component ``C23 = tilt_const + tilt_cos cos(psi) + tilt_sin sin(psi)`` (a tilt fixed in b0
gives the sinusoid, a stand tilt fixed in n the constant), in the parameter's unit times
mrad. Their heading signatures are the mixed derivatives d2h/(dp dC23) of the symbolic
model, so nothing is written by hand. The untilted part of such a parameter is a constant
heading offset (for lambda2: the skew part of Lambda), absorbed by ``offset``.
"""
import hashlib
from functools import cached_property, lru_cache

import casadi as ca
import numpy as np

from .. import units
from ..compile_cache import available, compiled
from .effects import Param
from .inputs import RUN_FIELDS, RunInputs
from .symbolic import (Operating, ErrorModel, alignment_rates_b0, averaged_rate_b0,
                       heading_error_alignment)

#: a 1-mrad tilt must move the heading by this much per display unit for a parameter to
#: count as tilt-coupled
_COUPLING_FLOOR = 1e-3 * units.ARCSEC
#: pitch/roll beyond this (rad) leave the small-tilt regime the catalogue assumes
MAX_TILT = 2.0 * units.DEG


@lru_cache(maxsize=64)
def _measurement(model, tilt_known):
    from .cache import load_or_build

    return load_or_build(MeasurementModel, model, tilt_known)


def _chain(model, p, x, covariate_names):
    """The operating point of one run and the error model its effects build."""
    v = RunInputs(x, covariate_names)
    op = Operating(Omega=v.rate, psi=v.azimuth, theta=v.pitch, gamma=v.roll, L=v.latitude,
                   t_start=v.t_start, duration=v.duration, covariates=v.covariates)
    errors = ErrorModel()
    for e in model.effects:
        e.act(p, op, errors)
    return op, errors


def symbolic_rate(model, p, x, covariate_names, omega_ie_b0=None):
    """The chain of one run up to the revolution-averaged computed Earth rate in b0.

    ``p``: dict of SI SX (or numbers) per parameter; ``x``: the run inputs; ``omega_ie_b0``:
    optional stand-in (e.g. a symbol) for the true Earth rate in b0. Returns
    ``(op, errors, omega_b0, degree)``; without encoder harmonics (``errors.encoder_terms``
    empty) the heading error is ``heading_error_gyrocompass(op, omega_b0) -
    errors.reference_error``; with them the alignment splits the mean
    (:func:`~hse_opt.model.symbolic.heading_error_alignment`).
    """
    op, errors = _chain(model, p, x, covariate_names)
    omega_b0, degree = averaged_rate_b0(op, errors, model.geometry, omega_ie_b0=omega_ie_b0)
    return op, errors, omega_b0, degree


def _symbolic_heading(model, p, x, covariate_names):
    """Heading error (rad) of one run for parameters ``p`` (dict of SI SX) and inputs x."""
    op, errors = _chain(model, p, x, covariate_names)
    coarse, mean, degree = alignment_rates_b0(op, errors, model.geometry)
    return heading_error_alignment(op, coarse, mean) - errors.reference_error, degree


class MeasurementModel:
    """h(p; run) and its Jacobian for one model and one tilt mode.

    Attributes
    ----------
    params : tuple of Param
        In the order of ``p``; values of ``p`` are SI (``display * param.scale``).
    names : tuple of str
    degree : int
        Trigonometric degree in the table angle averaged exactly (degree + 1 samples).
    h, J : casadi.Function
        ``h(p, x) -> heading error`` (rad) and ``J(p, x) -> dh/dp`` (1 x n_p) of one run.
    hJ : casadi.Function
        ``hJ(p, x) -> [h; dh/dp']`` ((1 + n_p) x 1): both from one graph.
    """

    def __init__(self, model, tilt_known):
        self.model = model
        self.tilt_known = tilt_known
        base = model.params
        self.covariates = model.covariates
        n_x = len(RUN_FIELDS) + len(self.covariates)
        x = ca.SX.sym("x", n_x)
        p_sym = {q.name: ca.SX.sym(q.name) for q in base}
        if tilt_known:
            h, self.degree = _symbolic_heading(model, p_sym, x, self.covariates)
            params, p_vec = base, ca.vertcat(*[p_sym[q.name] for q in base])
        else:
            h, self.degree, params, p_vec = self._free_tilt(model, base, p_sym, x)
        self.params = tuple(params)
        self.names = tuple(q.name for q in self.params)
        self.scale = np.array([q.scale for q in self.params])
        self.nonlinear = tuple(n for e in model.effects for n in e.nonlinear if n in self.names)
        self.h = ca.Function("h", [p_vec, x], [h], ["p", "x"], ["heading_err"])
        dh = ca.jacobian(h, p_vec)
        self.J = ca.Function("J", [p_vec, x], [dh], ["p", "x"], ["dh_dp"])
        # h and dh/dp in one Function sharing the graph (the fit's iterations need both)
        self.hJ = ca.Function("hJ", [p_vec, x], [ca.densify(ca.vertcat(h, dh.T))], ["p", "x"], ["h_dh_dp"])
        self.n_x = n_x

    # ---- kept on disk by hse_opt.model.cache ------------------------------------------
    _FUNCTIONS = ("h", "J", "hJ")

    def __getstate__(self):
        state = {k: v for k, v in self.__dict__.items() if k not in ("model", "_batch", "graph")}
        for name in self._FUNCTIONS:
            state[name] = getattr(self, name).serialize()
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        for name in self._FUNCTIONS:
            setattr(self, name, ca.Function.deserialize(state[name]))
        self.graph = {name: hashlib.sha256(state[name].encode()).hexdigest() for name in self._FUNCTIONS}
        self.model = None

    @cached_property
    def graph(self):
        """Digest of each Function's serialisation (the compile cache's key, without
        serialising the mapped Functions again)."""
        return {name: hashlib.sha256(getattr(self, name).serialize().encode()).hexdigest()
                for name in self._FUNCTIONS}

    def attach(self, model):
        """This model, unpickled, for the live ``model`` it was built from."""
        self.model = model
        return self

    def _free_tilt(self, model, base, p_sym, x):
        """Replace tilt-coupled parameters by free C23 coefficients (module docstring)."""
        t = ca.SX.sym("t", 3)  # tilt_cos, tilt_sin, tilt_const: C23 coefficients
        psi = RunInputs(x).azimuth
        # a tilt whose C23 is tilt_cos cos(psi) + tilt_sin sin(psi) + tilt_const
        tilted = {"pitch": t[1] + ca.sin(psi) * t[2], "roll": -t[0] - ca.cos(psi) * t[2]}
        x_t = ca.vertcat(*[tilted.get(f, x[i]) for i, f in enumerate(RUN_FIELDS)], x[len(RUN_FIELDS):])
        h_t, degree = _symbolic_heading(model, p_sym, x_t, self.covariates)
        p_all = ca.vertcat(*[p_sym[q.name] for q in base])
        p0 = ca.DM([q.nominal * q.scale for q in base])
        mixed = ca.jacobian(ca.jacobian(h_t, t), p_all)  # 3 x n_p
        h0 = ca.substitute(h_t, t, ca.DM.zeros(3))
        dh0 = ca.jacobian(h0, p_all)
        coupled = self._coupled(base, mixed, dh0, x, p_all, p0, t)
        kept = [q for q, c in zip(base, coupled) if not c]
        params, extra = list(kept), 0
        for j, q in enumerate(base):
            if not coupled[j]:
                continue
            for k, label in enumerate(("tilt_cos", "tilt_sin", "tilt_const")):
                coef = ca.SX.sym(f"{q.name}*{label}")
                bound = max(abs(q.lower), abs(q.upper)) * MAX_TILT / units.MRAD
                params.append(Param(f"{q.name}*{label}", f"{q.unit}*mrad", q.scale * units.MRAD,
                                    0.0, -bound, bound,
                                    f"{q.name} times the {label[5:]} coefficient of C23 (tilt unknown)"))
                p_sym[params[-1].name] = coef
                basis = ca.substitute(mixed[k, j], ca.vertcat(p_all, t), ca.vertcat(p0, ca.DM.zeros(3)))
                extra = extra + coef * basis
        # coupled parameters stay at nominal in the untilted part
        dropped = [q for q, c in zip(base, coupled) if c]
        if dropped:
            h0 = ca.substitute(h0, ca.vertcat(*[p_sym[q.name] for q in dropped]),
                               ca.DM([q.nominal * q.scale for q in dropped]))
        p_vec = ca.vertcat(*[p_sym[q.name] for q in params])
        return h0 + extra, degree, params, p_vec

    def _coupled(self, base, mixed, dh0, x, p_all, p0, t):
        """Which base parameters couple to heading through the tilt (numerically, over a
        spread of operating points)."""
        f = ca.Function("coupling", [x, p_all, t], [mixed, dh0])
        rng = np.random.default_rng(12345)
        n = 16
        X = np.zeros((x.shape[0], n))
        v = RunInputs(X)
        v.rate = rng.choice([-1, 1], n) * rng.uniform(10, 80, n) * units.DEG_PER_S
        v.azimuth = rng.uniform(0, 2 * np.pi, n)
        v.latitude = rng.uniform(-1.0, 1.0, n)
        v.t_start = rng.uniform(0, 7200, n)
        v.duration = 600.0
        X[len(RUN_FIELDS):] = rng.normal(size=(X.shape[0] - len(RUN_FIELDS), n))  # covariates
        mixed_v, dh0_v = f.map(n)(X, p0, ca.DM.zeros(3))
        mixed_v = np.abs(np.array(mixed_v)).reshape(3, n, -1).max(axis=(0, 1))
        scale = np.array([q.scale for q in base])
        return mixed_v * units.MRAD * scale > _COUPLING_FLOOR

    # ---- numeric evaluation -------------------------------------------------------------
    @property
    def nominal(self):
        """Nominal parameter values, SI."""
        return np.array([q.nominal * q.scale for q in self.params])

    def inputs(self, rate, azimuth, latitude, duration=600.0, t_start=None, pitch=None,
               roll=None, covariates=None):
        """Run-input matrix ``x`` (n_x, n_runs) from SI arrays.

        Parameters
        ----------
        rate : array_like, shape (n,) or float
            Signed bias rate Omega, rad/s. Every argument is an array of the runs or a scalar
            shared by them (numpy broadcasting); the run count is the broadcast size.
        azimuth, latitude : array_like, shape (n,)
            Stand azimuth (taken as the heading of b0) and latitude, rad.
        duration : array_like or float
            Alignment length, s.
        t_start : array_like, optional
            Time since power-on at the start of each alignment, s; when absent the run order
            stands in (run i starts at i * duration).
        pitch, roll : array_like, optional
            Tilt of b0 from leveling, rad. Required when ``tilt_known``; ignored otherwise.
        covariates : mapping name -> array_like, optional
            The columns this model's covariate effects use.
        """
        covariates = dict(covariates or {})
        given = [rate, azimuth, latitude, duration, t_start, pitch, roll,
                 *(covariates.get(c) for c in self.covariates)]
        names = ("rate", "azimuth", "latitude", "duration", "t_start", "pitch", "roll", *self.covariates)
        shapes = {k: np.shape(v) for k, v in zip(names, given) if v is not None}
        try:
            shape = np.broadcast_shapes(*shapes.values())
        except ValueError:
            shape = None
        if shape is None or len(shape) > 1:
            raise ValueError("run inputs must be 1-D arrays of one length (or scalars); got shapes "
                             + ", ".join(f"{k} {v}" for k, v in shapes.items()))
        n = shape[0] if shape else 1
        rate = np.broadcast_to(np.asarray(rate, dtype=float), (n,))
        cols = {"rate": rate}
        for name, v in (("azimuth", azimuth), ("latitude", latitude), ("duration", duration)):
            cols[name] = np.broadcast_to(np.asarray(v, dtype=float), (n,))
        if t_start is None:
            t_start = np.concatenate([[0.0], np.cumsum(cols["duration"][:-1])])
        cols["t_start"] = np.broadcast_to(np.asarray(t_start, dtype=float), (n,))
        if self.tilt_known:
            if pitch is None or roll is None:
                raise ValueError("pitch and roll are required for a tilt-known measurement model; "
                                 "use model.measurement(tilt_known=False) for runs without them")
            cols["pitch"] = np.broadcast_to(np.asarray(pitch, dtype=float), (n,))
            cols["roll"] = np.broadcast_to(np.asarray(roll, dtype=float), (n,))
        else:
            cols["pitch"] = cols["roll"] = np.zeros(n)
        missing = [c for c in self.covariates if c not in covariates]
        if missing:
            raise ValueError(f"covariate columns {missing} are required by the model's effects; "
                             f"given: {sorted(covariates) or 'none'}")
        X = np.empty((self.n_x, n))
        for i, f in enumerate(RUN_FIELDS):
            X[i] = cols[f]
        for i, c in enumerate(self.covariates):
            X[len(RUN_FIELDS) + i] = np.broadcast_to(np.asarray(covariates[c], dtype=float), (n,))
        _check_inputs(X, self.tilt_known)
        return X

    def inputs_from_runs(self, runs):
        """Run-input matrix from a :class:`hse_opt.data.Runs` or :class:`hse_opt.data.Plan`
        (plans give their deliberate tilt ``tilt_x``/``tilt_y`` as pitch/roll)."""
        pitch = getattr(runs, "pitch", None)
        roll = getattr(runs, "roll", None)
        if pitch is None and hasattr(runs, "tilt_x"):
            pitch, roll = runs.tilt_y, runs.tilt_x
        missing = [c for c in self.covariates if c not in runs.covariates]
        for c in missing:
            if hasattr(runs, "covariate"):  # names the row that made the column text, or the columns there are
                runs.covariate(c, f"the effect covariate:{c}")
        if missing:
            raise ValueError(f"{runs.source}: covariate columns {missing} are required by the model's "
                             f"effects; the file has {sorted(runs.covariates) or 'none'}")
        return self.inputs(runs.rate, runs.azimuth, runs.latitude, runs.duration, runs.t_start,
                           pitch, roll, {c: runs.covariates[c] for c in self.covariates})

    def vector(self, values=None, **kw):
        """SI parameter vector from display-unit values by name; the rest at nominal.

        ``m.vector(lambda2=4.2, offset=-3)`` or ``m.vector({"lambda2": 4.2})``.
        """
        values = {**(values or {}), **kw}
        unknown = sorted(set(values) - set(self.names))
        if unknown:
            raise ValueError(f"unknown parameter(s) {unknown}; this model has: {', '.join(self.names)} (allowed: "
                             "those names)")
        out = []
        for q in self.params:
            v = float(values.get(q.name, q.nominal))
            if not np.isfinite(v):
                raise ValueError(f"parameter {q.name!r} = {v}; allowed: a finite value in {q.unit}")
            out.append(v * q.scale)
        return np.array(out)

    def predict(self, p, X, jit=None):
        """Heading error (rad) of every run: ``p`` SI (n_p,), ``X`` (n_x, n) -> (n,).
        ``jit``: compile the batch Function (default: for large batches, see BatchEvaluator)."""
        return self._batch["h"](self._p(p), X, jit)

    def jacobian(self, p, X, jit=None):
        """dh/dp (rad per SI unit) of every run: (n, n_p)."""
        return self._batch["J"](self._p(p), X, jit)

    def held_jacobian(self, varying, columns):
        """The Jacobian with every parameter but ``varying`` held at its nominal value.

        The held values are folded into the graph when it is built (once per ``varying`` and
        ``columns``; common subexpressions merged), which spares every operation they cancel:
        the Jacobian of a model with the catalogue's other effects at their nominal 0 (the
        alias budget's, :mod:`hse_opt.aliasing`) takes 40 % fewer than :meth:`jacobian`.

        Parameters
        ----------
        varying : tuple of int
            Indices of the parameters given on each call.
        columns : tuple of int
            Indices of the parameters whose columns are returned.

        Returns
        -------
        BatchEvaluator
            ``(p, X, jit) -> dh/dp[:, columns]`` (n, len(columns), rad per SI unit) of every
            run at the parameters ``p`` (shape (len(varying),), SI) and the rest nominal.
        """
        key = ("J held", tuple(varying), tuple(columns))
        if key not in self._batch:
            p, x = ca.SX.sym("p", len(varying)), ca.SX.sym("x", self.n_x)
            full = [ca.SX(v) for v in self.nominal]
            for j, i in enumerate(varying):
                full[i] = p[j]
            dh = self.J(ca.vertcat(*full), x)[:, list(columns)]
            f = ca.Function("J_held", [p, x], [dh], ["p", "x"], ["dh_dp"], {"cse": True})
            graph = f"{self.graph['J']}|held|{key[1]}|{key[2]}|{self.nominal.tolist()}|cse"
            self._batch[key] = BatchEvaluator(f, graph=hashlib.sha256(graph.encode()).hexdigest())
        return self._batch[key]

    def predict_graph(self, p, X, jit=None):
        """:meth:`predict` inside a CasADi graph: MX ``p`` (n_p x 1), ``X`` (n_x x n) -> MX (1 x n)."""
        return self._batch["h"].symbolic(p, X, jit)

    def jacobian_graph(self, p, X, jit=None):
        """:meth:`jacobian` inside a CasADi graph, transposed: MX (n_p x n), column i = dh_i/dp."""
        return self._batch["J"].symbolic(p, X, jit)

    @cached_property
    def _batch(self):
        return {"h": BatchEvaluator(self.h, graph=self.graph["h"]),
                "J": BatchEvaluator(self.J, graph=self.graph["J"])}

    def _p(self, p):
        p = np.asarray(p, dtype=float).ravel()
        if p.shape != (len(self.params),):
            raise ValueError(f"p must have {len(self.params)} values {self.names}, got {p.shape[0]}")
        if not np.all(np.isfinite(p)):
            bad = [n for n, v in zip(self.names, p) if not np.isfinite(v)]
            raise ValueError(f"parameters {bad} are not finite")
        return p

    def parameter_index(self, name):
        try:
            return self.names.index(name)
        except ValueError:
            raise ValueError(f"unknown parameter {name!r}; allowed: this model's {', '.join(self.names)}") from None


def _check_inputs(X, tilt_known):
    names = RUN_FIELDS
    bad = ~np.isfinite(X)
    if bad.any():
        i, j = np.argwhere(bad)[0]
        label = names[i] if i < len(names) else f"covariate {i - len(names)}"
        raise ValueError(f"run input {label!r} of run index {j} is {X[i, j]}; allowed: finite values")
    v = RunInputs(X)
    lat = np.abs(v.latitude)
    if (lat > np.pi / 2).any():
        j = int(np.argmax(lat))
        raise ValueError(f"latitude of run index {j} is {np.degrees(v.latitude[j]):.6g} deg; "
                         "allowed: -90 to 90 deg")
    if (v.duration <= 0).any():
        j = int(np.argmin(v.duration))
        raise ValueError(f"duration of run index {j} is {v.duration[j]} s; allowed: > 0")
    if tilt_known:
        tilt = np.vstack([v.pitch, v.roll])
        if (np.abs(tilt) > MAX_TILT).any():
            i, j = np.unravel_index(np.argmax(np.abs(tilt)), tilt.shape)
            raise ValueError(f"{('pitch', 'roll')[i]} of run index {j} is {np.degrees(tilt[i, j]):.6g} "
                             f"deg; allowed: |tilt| <= {np.degrees(MAX_TILT):g} deg (first-order tilt terms)")


class BatchEvaluator:
    """Evaluate a per-run Function ``f(p, x) -> row`` over many runs with ``Function.map``.

    Runs go through in chunks of a fixed size (a power of two up to ``max_chunk``, the last
    chunk padded), each chunk one call of the mapped Function on numpy memory (no per-run
    Python work, no copies into CasADi matrices). From ``jit_above`` runs on, the Function
    mapped over ``jit_chunk`` runs is compiled to C once per machine
    (:mod:`hse_opt.compile_cache`) and evaluates every batch size; if compiling fails, the
    virtual machine is used and a warning says why. Smaller batches use the compiled Function
    too once it is at hand (loaded, or in the disk cache): nothing to compile then, and about
    ten times faster. ``jit=True/False`` on a call overrides these rules. ``graph``: a
    digest of ``fun``'s serialisation, when known (the compile cache's key without serialising
    the mapped Function).
    ``exact=True``: a call that is not compiled maps exactly its ``n`` runs (up to
    ``max_chunk``) instead of padding to a power of two - a third less work at 100 runs, for
    a mapped Function per run count (~0.4 ms to build; the last ``_MAX_EXACT`` kept): for
    callers that evaluate one run count many times, such as a fit's iterations.
    """

    _MAX_EXACT = 64

    def __init__(self, fun, max_chunk=4096, jit_above=1000, exact=False, jit_chunk=256, graph=None):
        self.fun = fun
        self.graph = graph
        self.n_out = fun.nnz_out(0)
        self.max_chunk = max_chunk
        self.jit_above = jit_above
        self.jit_chunk = jit_chunk
        self.exact = exact
        self._cache = {}
        self._functions = {}
        self._on_disk = None

    def _chunk(self, n, jit=False):
        if jit:
            return self.jit_chunk
        return min(self.max_chunk, 1 << max(0, int(np.ceil(np.log2(max(n, 1))))))

    def function(self, chunk, jit=False):
        """The mapped Function over ``chunk`` runs (compiled when ``jit``), built once:
        ``(p, X[n_x x chunk]) -> (1 x chunk * n_out)``, run-major."""
        key = (chunk, jit)
        if key not in self._functions:
            f = self._map(chunk)
            self._functions[key] = compiled(f, self._graph(chunk)) if jit else f
        return self._functions[key]

    def _compiled_at_hand(self):
        """Whether the compiled batch Function is loaded or on disk (then small batches use it
        too: no compile to wait for, and it is about ten times faster than the virtual
        machine). Asked of the disk once per evaluator."""
        if (self.jit_chunk, True) in self._functions:
            return True
        if self._on_disk is None:
            self._on_disk = available(self._map(self.jit_chunk), self._graph(self.jit_chunk))
        return self._on_disk

    def _map(self, chunk):
        return self.fun.map(f"{self.fun.name()}_map", "serial", chunk, [0], [])

    def _graph(self, chunk):
        return None if self.graph is None else f"{self.graph}|map|serial|{chunk}|[0]"

    def _mapped(self, chunk, jit):
        key = (chunk, jit)
        if key not in self._cache:
            self._cache[key] = self.function(chunk, jit).buffer()
        return self._cache[key]

    def symbolic(self, p, X, jit=None):
        """The same evaluation inside a CasADi graph: ``p`` (n_p x 1) and ``X`` (n_x x n) MX
        -> MX (n_out x n), through the chunked mapped Functions (shared with numeric calls).
        The graph keeps CasADi's virtual machine whatever ``jit`` says: solvers differentiate
        it, and a compiled library has no derivatives."""
        n = X.shape[1]
        chunk = self._chunk(n)
        f = self.function(chunk)
        cols = []
        for i in range(0, n, chunk):
            m = min(chunk, n - i)
            Xi = X[:, i:i + m]
            if m < chunk:
                Xi = ca.horzcat(Xi, ca.repmat(X[:, n - 1], 1, chunk - m))
            cols.append(ca.reshape(f(p, Xi), self.n_out, chunk)[:, :m])
        return ca.horzcat(*cols)

    def __call__(self, p, X, jit=None):
        n = X.shape[1]
        out = np.empty((n, self.n_out))
        if n == 0:
            return out if self.n_out > 1 else out[:, 0]
        jit = (n >= self.jit_above or self._compiled_at_hand()) if jit is None else bool(jit)
        chunk = n if self.exact and not jit and n <= self.max_chunk else self._chunk(n, jit)
        if (chunk, jit) not in self._cache and len(self._cache) >= self._MAX_EXACT:
            for key in [key for key in self._cache if not key[1]]:  # compiled ones stay
                del self._cache[key], self._functions[key]
        buf, trigger = self._mapped(chunk, jit)
        XT = np.ascontiguousarray(X.T)
        p = np.ascontiguousarray(p, dtype=float)
        buf.set_arg(0, memoryview(p))
        full = n - n % chunk
        for i in range(0, full, chunk):
            buf.set_arg(1, memoryview(XT[i:i + chunk].reshape(-1)))
            buf.set_res(0, memoryview(out[i:i + chunk].reshape(-1)))
            trigger()
        if full < n:
            pad_x = np.repeat(XT[-1:], chunk, axis=0)
            pad_x[: n - full] = XT[full:]
            pad_out = np.empty((chunk, self.n_out))
            buf.set_arg(1, memoryview(pad_x.reshape(-1)))
            buf.set_res(0, memoryview(pad_out.reshape(-1)))
            trigger()
            out[full:] = pad_out[: n - full]
        return out if self.n_out > 1 else out[:, 0]

