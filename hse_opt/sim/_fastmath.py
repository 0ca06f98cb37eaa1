"""Fast, accurate cos/sin of nearly linear phase sequences (private helpers of the simulator).

``np.sin`` costs about 15 ns per float64 here, and the simulator needs cos and sin of the
table angle at 500 Hz. The table angle grows almost linearly with the sample index, so:

* a :class:`PhaseTable` holds ``cos`` and ``sin`` of ``k * dphi`` for one chunk length;
  a chunk's start phase ``phi0`` is turned in once per chunk by the callers (on their
  coefficients or block sums), or per sample by the angle-addition formula
  (:meth:`PhaseTable.cos_sin`);
* a small deviation ``d`` from the linear phase is folded in with its Taylor series
  (:func:`rotate_small`).

Both are exact to a few 1e-16 (checked against ``np.sin`` in the tests); a deviation larger
than :data:`MAX_DEVIATION` falls back to ``np.cos``/``np.sin``.
"""
from __future__ import annotations

import math

import numpy as np

from hse_opt.align._angles import MAX_DEVIATION, SMALL_DEVIATION, rotate



#: entries of a table computed directly; the rest follow by doubling
_SEED = 64


class PhaseTable:
    """cos and sin of ``phi0 + k * dphi`` for ``k = 0 .. m-1``, ``m <= n`` (rad).

    Built by doubling: the first :data:`_SEED` entries with ``np.cos``/``np.sin``, then each
    block ``k + j`` from the block ``k`` by the angle-addition formula with ``cos(j dphi)``,
    ``sin(j dphi)`` (about a tenth of the cost of ``np.cos``/``np.sin`` on the whole table,
    and a few 1e-16 from the exact values at every size)."""

    def __init__(self, dphi, n):
        self.dphi = dphi = float(dphi)
        c, s = self.c, self.s = np.empty(n), np.empty(n)
        j = min(n, _SEED)
        k = dphi * np.arange(j, dtype=float)
        np.cos(k, out=c[:j])
        np.sin(k, out=s[:j])
        while j < n:
            m = min(j, n - j)
            cj, sj = math.cos(j * dphi), math.sin(j * dphi)
            np.multiply(c[:m], cj, out=c[j:j + m])
            c[j:j + m] -= s[:m] * sj
            np.multiply(s[:m], cj, out=s[j:j + m])
            s[j:j + m] += c[:m] * sj
            j += m

    def cos_sin(self, phi0, m):
        """Arrays (m,) of ``cos`` and ``sin`` of ``phi0 + k dphi``."""
        c0, s0 = math.cos(phi0), math.sin(phi0)
        cb, sb = self.c[:m], self.s[:m]
        c = cb * c0
        c -= sb * s0
        s = sb * c0
        s += cb * s0
        return c, s


def exp_linear(rate, n, out=None):
    """``exp(rate * k)`` for ``k = 0 .. n-1``, by doubling (as :class:`PhaseTable`): the
    relative error stays within a few 1e-16 for ``|rate| n`` up to tens. Written into
    ``out`` (shape (n,)) when given."""
    out = np.empty(n) if out is None else out
    j = min(n, _SEED)
    np.exp(rate * np.arange(j, dtype=float), out=out[:j])
    while j < n:
        m = min(j, n - j)
        np.multiply(out[:m], math.exp(rate * j), out=out[j:j + m])
        j += m
    return out


def rotate_small(c, s, d, out, work, dmax):
    """cos and sin of ``phase + d`` from ``c = cos(phase)``, ``s = sin(phase)`` and a small
    ``d`` (rad); arrays of one shape (m,). ``dmax`` is a bound on ``|d|`` (at most
    :data:`MAX_DEVIATION`): below :data:`SMALL_DEVIATION` the ``d^4 / 24`` term of ``cos d``
    (< 7e-17) is left out. Written into ``out`` (shape (2, m)), with ``work`` (shape (3, m))
    as scratch; neither may overlap the inputs. Returns ``(cos, sin)``."""
    w0, cd, tmp = work[0], work[1], work[2]
    d2 = np.multiply(d, d, out=w0)
    if dmax > SMALL_DEVIATION:                 # cos d = 1 + d^2 (d^2 / 24 - 1 / 2)
        np.multiply(d2, 1.0 / 24.0, out=cd)
        cd -= 0.5
        cd *= d2
    else:                                      # cos d = 1 - d^2 / 2
        np.multiply(d2, -0.5, out=cd)
    cd += 1.0
    sd = d2                                    # sin d = d (1 - d^2 / 6)
    sd *= -1.0 / 6.0
    sd += 1.0
    sd *= d
    return rotate(c, s, cd, sd, out, tmp)


def cos_sin_linear(phi0, dphi, n):
    """cos and sin of ``phi0 + k * dphi`` for ``k = 0 .. n-1`` (rad), shape (n,) each."""
    return PhaseTable(dphi, n).cos_sin(phi0, n)


def cos_sin(phase, table=None, out=None):
    """cos and sin of a phase sequence that is nearly linear in its index (rad, shape (n,)).

    The phase is split into the line ``phase[0] + k * dphi`` and a deviation; ``dphi`` is
    ``table.dphi`` when a :class:`PhaseTable` of at least ``n`` entries is given, else the
    slope through the first and last samples. Deviations within :data:`MAX_DEVIATION` use
    the fast path, larger ones ``np.cos``/``np.sin``. Returns ``(cos, sin)``, written into
    ``out`` (shape (2, n)) when given.
    """
    phase = np.asarray(phase, dtype=float)
    n = phase.shape[0]
    if out is None:
        out = np.empty((2, n))
    if table is None or table.c.shape[0] < n:
        table = PhaseTable((phase[-1] - phase[0]) / max(n - 1, 1), n)
    d = phase - phase[0]
    d -= table.dphi * np.arange(n, dtype=float)
    dmax = max(float(d.max()), -float(d.min())) if n else 0.0
    if n < 3 or not dmax <= MAX_DEVIATION:
        np.cos(phase, out=out[0])
        np.sin(phase, out=out[1])
        return out[0], out[1]
    c, s = table.cos_sin(float(phase[0]), n)
    return rotate_small(c, s, d, out, np.empty((3, n)), dmax)


def splits_words(rng):
    """True when ``rng``'s float32 uniforms are its 64-bit words split in two, low half first,
    and no half word is pending: then :func:`uniform_bits` reads the words directly. This
    holds for numpy's PCG64, PCG64DXSM, SFC64 and Philox (their ``next_uint32``), not
    MT19937; the test suite checks it against ``Generator.random``."""
    return rng.bit_generator.state.get("has_uint32") == 0


def uniform_bits(rng, k, split=False):
    """The next ``k`` float32 uniforms of ``rng`` (``Generator.random(k, dtype=float32)``)
    times ``2**24``: their 24-bit integers, int32 (k,). ``split`` (:func:`splits_words`, and
    ``k`` even) reads the 64-bit words instead (40 % faster; the same numbers: numpy forms a
    float32 uniform as ``(next_uint32 >> 8) * 2**-24``)."""
    if split and k % 2 == 0:
        w = rng.bit_generator.random_raw(k // 2).view(np.uint32)
        w >>= 8
        return w.view(np.int32)
    u = rng.random(k, dtype=np.float32)
    u *= np.float32(2.0 ** 24)
    return u.astype(np.int32)


def box_muller_f32(bits, scale):
    """Gaussian noise from uniforms given as 24-bit integers (:func:`uniform_bits`, shape
    (b, 2h), overwritten): row ``i``'s first half is the radius's uniform, its second half
    the angle's, and the row is scaled by ``scale[i]``. Returns (b, 2h) float32: ``r cos`` in
    the first half, ``r sin`` in the second.

    With ``u = bits * 2**-24`` the float32 uniform, ``r = sqrt(-2 ln(1 - u))`` and the angle
    ``2 pi u`` are computed as ``(2**24 - bits) * 2**-24`` and ``bits * (2 pi 2**-24)``:
    products by powers of two are exact, so these are the float32 numbers of the textbook
    formulas. Exact in distribution up to the 24-bit resolution of the uniforms (the tails
    are cut at 5.77 sigma, a probability of 8e-9 per sample); three times faster here than
    ``Generator.standard_normal(dtype=float32)`` (the ziggurat), as numpy's float32
    log/sqrt/sin/cos are vectorised. Rows drawn one after the other from one stream are
    transformed as if each had its own call (a Generator's float32 stream does not depend on
    how it is split into calls)."""
    b, k = bits.shape
    h = k // 2
    out = np.empty((b, k), dtype=np.float32)
    r = np.empty((b, h), dtype=np.float32)
    np.subtract(1 << 24, bits[:, :h], out=bits[:, :h])  # 2**24 (1 - u), in (0, 2**24]: log is finite
    np.copyto(r, bits[:, :h], casting="unsafe")
    r *= np.float32(2.0 ** -24)
    np.log(r, out=r)
    r *= np.float32(-2.0)
    np.sqrt(r, out=r)
    r *= np.asarray(scale, dtype=np.float32)[:, None]
    a = out[:, h:]
    np.copyto(a, bits[:, h:], casting="unsafe")
    a *= np.float32(2.0 * math.pi) * np.float32(2.0 ** -24)
    np.cos(a, out=out[:, :h])
    np.sin(a, out=a)
    out.reshape(b, 2, h)[...] *= r[:, None, :]
    return out
