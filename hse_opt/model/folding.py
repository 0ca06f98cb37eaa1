"""Fold the linear parts of a CasADi SX graph: fewer operations, same function.

CasADi's SX keeps the order in which an expression was built: ``C1 (C2 (C3 v))`` with
constant matrices stays three matrix-vector products even when ``C1 C2 C3`` is one constant
matrix, and a revolution average over N table angles repeats the chain N times. With the
parameters fixed (the compensation a navigation computer runs) most of the measurement
model is such a chain. :func:`fold_linear` rewrites the graph so that every sum, difference,
negation and product or quotient by a constant is carried as a linear combination of the
graph's nonlinear nodes ("atoms": inputs, products of two non-constant terms, sin, atan2,
...); a combination is written out only where a nonlinear operation or an output needs it.
The result is the same function up to floating-point reassociation (relative 1e-16 per
operation), usually with far fewer operations.

A combination of more than ``max_terms`` atoms is written out at once and becomes an atom
itself, so that a long shared sum is not repeated in every place that uses it. Shorter
combinations are written out in full wherever they are used, which can cost more than the
original graph when a combination of many atoms feeds many nonlinear operations: compare
``n_instructions()`` and keep the smaller (as :func:`hse_opt.export.compensation_function` does).
"""
import math

import casadi as ca

__all__ = ["fold_linear", "cost", "SMALL_ANGLE"]

_LINEAR = {ca.OP_ADD, ca.OP_SUB, ca.OP_NEG, ca.OP_MUL, ca.OP_DIV, ca.OP_TWICE, ca.OP_ASSIGN}


class _Lin:
    """``const + sum(coef[k] * atoms[k])`` over atom ids; ``sx`` caches the written-out form."""

    __slots__ = ("coef", "const", "sx")

    def __init__(self, coef, const):
        self.coef = coef
        self.const = const
        self.sx = None

    @property
    def is_constant(self):
        return not self.coef


def _combine(a, b, sign):
    coef = dict(a.coef)
    for k, v in b.coef.items():
        c = coef.get(k, 0.0) + sign * v
        if c == 0.0:
            coef.pop(k, None)
        else:
            coef[k] = c
    return _Lin(coef, a.const + sign * b.const)


def _scale(a, s):
    if s == 0.0:
        return _Lin({}, 0.0)
    return _Lin({k: v * s for k, v in a.coef.items()}, a.const * s)


#: sin and cos of a ``small`` input by their Taylor series to x^11 / x^12: exact to double
#: rounding for |x| <= SMALL_ANGLE rad (remainder < 5e-16 |x|)
SMALL_ANGLE = 0.2
_SIN = [(-1) ** k / math.factorial(2 * k + 1) for k in range(6)]
_COS = [(-1) ** k / math.factorial(2 * k) for k in range(7)]


def _series(x, coefficients, odd):
    """Horner in x^2: ``x * sum c_k x^2k`` (odd) or ``sum c_k x^2k``."""
    x2 = x * x
    s = ca.SX(coefficients[-1])
    for c in reversed(coefficients[:-1]):
        s = s * x2 + c
    return x * s if odd else s


def cost(f):
    """A rough operation count of SX Function ``f`` for choosing between forms: each
    instruction 1, each call of a transcendental function (sin, cos, atan2, exp, ...) 40."""
    plain = {ca.OP_INPUT, ca.OP_OUTPUT, ca.OP_CONST, ca.OP_ADD, ca.OP_SUB, ca.OP_MUL, ca.OP_DIV,
             ca.OP_NEG, ca.OP_SQ, ca.OP_TWICE, ca.OP_ASSIGN, ca.OP_FABS, ca.OP_SIGN, ca.OP_IF_ELSE_ZERO}
    ops = [f.instruction_id(k) for k in range(f.n_instructions())]
    return len(ops) + 39 * sum(op not in plain for op in ops)


def _small_atom(a, small_atoms):
    """The small input ``a`` is exactly (coefficient 1, no constant), else None."""
    if a.const == 0.0 and len(a.coef) == 1:
        (k, c), = a.coef.items()
        if c == 1.0 and k in small_atoms:
            return small_atoms[k]
    return None


def fold_linear(inputs, outputs, max_terms=16, small=()):
    """Rewrite ``outputs`` (list of SX in the symbols ``inputs``) with their linear parts folded.

    Parameters
    ----------
    inputs : list of casadi.SX
        Purely symbolic inputs (as for a ``casadi.Function``).
    outputs : list of casadi.SX
    max_terms : int
        A linear combination of more atoms is written out and becomes an atom.
    small : sequence of (int, int)
        ``(input, element)`` of inputs known to be small angles (e.g. pitch and roll): their
        sin and cos become Taylor series (exact to double rounding for |x| <= SMALL_ANGLE;
        a polynomial costs a fraction of a libm call).

    Returns
    -------
    list of casadi.SX
        Same shapes and sparsity as ``outputs``, in the same symbols.
    """
    f = ca.Function("fold", inputs, outputs, {"cse": True})
    atoms = []  # atom id -> SX scalar

    def atom(sx):
        atoms.append(sx)
        return _Lin({len(atoms) - 1: 1.0}, 0.0)

    def write(a):
        if a.sx is None:
            terms = []
            for k in sorted(a.coef):
                c = a.coef[k]
                terms.append(atoms[k] if c == 1.0 else -atoms[k] if c == -1.0 else c * atoms[k])
            s = terms[0] if terms else ca.SX(a.const)
            for t in terms[1:]:
                s = s + t
            if terms and a.const != 0.0:
                s = s + a.const
            a.sx = s
        return a.sx

    def bounded(a):
        return atom(write(a)) if len(a.coef) > max_terms else a

    in_nz = [[x.nz[i] for i in range(x.nnz())] for x in inputs]
    small = set(map(tuple, small))
    small_atoms = {}  # atom id -> SX of a small input
    out = [[ca.SX(0)] * o.nnz() for o in outputs]
    work = [None] * f.sz_w()
    for k in range(f.n_instructions()):
        op = f.instruction_id(k)
        i_in, i_out = f.instruction_input(k), f.instruction_output(k)
        if op == ca.OP_INPUT:
            work[i_out[0]] = atom(in_nz[i_in[0]][i_in[1]])
            if (i_in[0], i_in[1]) in small:
                small_atoms[len(atoms) - 1] = in_nz[i_in[0]][i_in[1]]
        elif op == ca.OP_OUTPUT:
            out[i_out[0]][i_out[1]] = write(work[i_in[0]])
        elif op == ca.OP_CONST:
            work[i_out[0]] = _Lin({}, float(f.instruction_constant(k)))
        elif op in _LINEAR:
            a = work[i_in[0]]
            b = work[i_in[1]] if len(i_in) > 1 else None
            if op == ca.OP_ADD:
                r = bounded(_combine(a, b, 1.0))
            elif op == ca.OP_SUB:
                r = bounded(_combine(a, b, -1.0))
            elif op == ca.OP_NEG:
                r = _scale(a, -1.0)
            elif op == ca.OP_TWICE:
                r = _scale(a, 2.0)
            elif op == ca.OP_ASSIGN:
                r = a
            elif op == ca.OP_MUL and (a.is_constant or b.is_constant):
                r = _scale(b, a.const) if a.is_constant else _scale(a, b.const)
            elif op == ca.OP_DIV and b.is_constant and b.const != 0.0:
                r = _scale(a, 1.0 / b.const)
            else:
                r = atom(ca.SX.binary(op, write(a), write(b)))
            work[i_out[0]] = r
        elif op in (ca.OP_SIN, ca.OP_COS) and _small_atom(work[i_in[0]], small_atoms) is not None:
            x = _small_atom(work[i_in[0]], small_atoms)
            work[i_out[0]] = atom(_series(x, _SIN, True) if op == ca.OP_SIN else _series(x, _COS, False))
        else:
            args = [write(work[i]) for i in i_in]
            if all(work[i].is_constant for i in i_in):
                value = ca.SX.binary(op, *args) if len(args) == 2 else ca.SX.unary(op, args[0])
                work[i_out[0]] = _Lin({}, float(ca.evalf(value)))
            elif len(args) == 2:
                work[i_out[0]] = atom(ca.SX.binary(op, *args))
            elif len(args) == 1:
                work[i_out[0]] = atom(ca.SX.unary(op, args[0]))
            else:
                raise ValueError(f"fold_linear: operation {op} with {len(args)} operands is not supported")
    result = []
    for o, nz in zip(outputs, out):
        r = ca.SX(o.sparsity())
        for i, v in enumerate(nz):
            r.nz[i] = v
        result.append(r)
    return result
