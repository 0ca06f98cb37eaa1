/* The raw-log path's passes over a record, compiled (hse_opt.align._kernels; private).

   What the quality checks and the Allan analysis take of a log, each array read once where
   numpy's route reads it two or three times, and the small loops that numpy runs as many
   passes over short arrays:
   - block_sums: a channel's sums over blocks of B samples with, for a gyro, their weighted
     sums (increment i of a block weighted B + 1 - i); encoder_steps: the encoder's steps'
     weighted sums over the same blocks and the extremes of all its steps
     (hse_opt/align/blocks.py, block_sums);
   - fit, residual: the table's deterministic part fitted out of the block sums (blocks.py,
     _fit_residual);
   - short_allan: the Allan analysis' clusters shorter than a block (noise.py, _short_allan);
   - octave_squares: its longer clusters' squared second differences (noise.py, _octave_squares);
   - step_statistic: the quality checks' step test statistic (steps.py, step_statistic);
   - quanta: the channels' and the encoder's quanta (_quanta.py, _row_quanta).
   Each takes the same steps as numpy's route (the same series, tables and doubling trees) and
   gives its figures to rounding (other summation orders; tests/test_align_kernels.py tests
   each against independent references and against numpy's route). Built by setup.py where a
   C compiler is present; without it the package takes numpy's route (hse_opt/align/_compiled.py).

   A block's sums are taken over W lanes (one vector register or two) in rows of W increments,
   two blocks at a time (independent chains for an out-of-order core). The weighted sum comes
   from the lanes' running sums: with R = B / W rows, increment k + W r (lane k, row r) has the
   weight B - k - W r = W (R - r) + (B - W R - k), and sum_r s_k(after row r) = sum_r (R - r)
   x(k + W r), so the block's weighted sum is sum_k W u_k + (B - W R - k) s_k, u_k the sum of
   lane k's running sums: additions only, no weight table.

   IEEE arithmetic throughout (no fast-math): a NaN or an infinity gives what numpy gives. */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>

#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__linux__)
/* AVX2 where the processor has it, chosen once at load (GCC function multi-versioning) */
#define CLONES __attribute__((target_clones("avx2", "default")))
#else
#define CLONES
#endif

#define W 8

/* a block's plain sum from its lanes, in one order in every branch (the plain sums do not
   depend on whether the weighted ones are taken); the tail's increments are added after it */
#define TREE(s) ((((s)[0] + (s)[4]) + ((s)[1] + (s)[5])) + (((s)[2] + (s)[6]) + ((s)[3] + (s)[7])))

/* sums (and weighted sums when w_out) of x[1 + b B .. (b + 1) B], b < nb. (The lanes stay in
   registers only where no pointer to them is taken: no helper function for the reductions.) */
CLONES static void
channel_blocks(const double *x, Py_ssize_t B, Py_ssize_t nb, double *s_out, double *w_out)
{
    const Py_ssize_t R = B / W, Bv = R * W;
    double cw[W];
    for (int k = 0; k < W; k++)
        cw[k] = (double)(B - Bv - k);
    x += 1;
    Py_ssize_t b = 0;
    if (w_out) {
        for (; b + 2 <= nb; b += 2, x += 2 * B) {          /* two blocks at a time */
            const double *y = x + B;
            double s0[W] = {0}, u0[W] = {0}, s1[W] = {0}, u1[W] = {0};
            for (Py_ssize_t r = 0; r < R; r++) {
                const double *p = x + r * W, *q = y + r * W;
                for (int k = 0; k < W; k++) {
                    s0[k] += p[k];
                    u0[k] += s0[k];
                    s1[k] += q[k];
                    u1[k] += s1[k];
                }
            }
            double S0 = TREE(s0), S1 = TREE(s1), W0 = 0, W1 = 0;
            for (int k = 0; k < W; k++) {
                W0 += (double)W * u0[k] + cw[k] * s0[k];
                W1 += (double)W * u1[k] + cw[k] * s1[k];
            }
            for (Py_ssize_t i = Bv; i < B; i++) {
                S0 += x[i];
                W0 += (double)(B - i) * x[i];
                S1 += y[i];
                W1 += (double)(B - i) * y[i];
            }
            s_out[b] = S0;
            s_out[b + 1] = S1;
            w_out[b] = W0;
            w_out[b + 1] = W1;
        }
        if (b < nb) {                                       /* the last of an odd count */
            double s0[W] = {0}, u0[W] = {0};
            for (Py_ssize_t r = 0; r < R; r++)
                for (int k = 0; k < W; k++) {
                    s0[k] += x[r * W + k];
                    u0[k] += s0[k];
                }
            double S0 = TREE(s0), W0 = 0;
            for (int k = 0; k < W; k++)
                W0 += (double)W * u0[k] + cw[k] * s0[k];
            for (Py_ssize_t i = Bv; i < B; i++) {
                S0 += x[i];
                W0 += (double)(B - i) * x[i];
            }
            s_out[b] = S0;
            w_out[b] = W0;
        }
        return;
    }
    for (; b < nb; b++, x += B) {
        double s[W] = {0};
        for (Py_ssize_t r = 0; r < R; r++) {
            const double *p = x + r * W;
            for (int k = 0; k < W; k++)
                s[k] += p[k];
        }
        double S = TREE(s);
        for (Py_ssize_t i = Bv; i < B; i++)
            S += x[i];
        s_out[b] = S;
    }
}

/* the weighted sums of the steps enc[k + 1] - enc[k] over blocks of B steps (step b B + i
   weighted B - i), b < nb, and the largest and smallest of all n - 1 steps (NaN if a step is) */
CLONES static void
encoder_blocks(const double *enc, Py_ssize_t n, Py_ssize_t B, Py_ssize_t nb, double *w_out,
               double *largest, double *smallest)
{
    const Py_ssize_t R = B / W, Bv = R * W;
    double cw[W], mx[W], mn[W];
    int nan[W];
    for (int k = 0; k < W; k++) {
        cw[k] = (double)(B - Bv - k);
        mx[k] = -INFINITY;
        mn[k] = INFINITY;
        nan[k] = 0;
    }
    Py_ssize_t b = 0;
    for (; b + 2 <= nb; b += 2) {
        const double *p = enc + b * B, *y = p + B;
        double s0[W] = {0}, u0[W] = {0}, s1[W] = {0}, u1[W] = {0};
        for (Py_ssize_t r = 0; r < R; r++) {
            const double *q = p + r * W, *z = y + r * W;
            for (int k = 0; k < W; k++) {
                double d = q[k + 1] - q[k], e = z[k + 1] - z[k];
                s0[k] += d;
                u0[k] += s0[k];
                s1[k] += e;
                u1[k] += s1[k];
                double hi = d > e ? d : e, lo = d < e ? d : e;
                mx[k] = hi > mx[k] ? hi : mx[k];
                mn[k] = lo < mn[k] ? lo : mn[k];
                nan[k] |= (d != d) | (e != e);
            }
        }
        double W0 = 0, W1 = 0;
        for (int k = 0; k < W; k++) {
            W0 += (double)W * u0[k] + cw[k] * s0[k];
            W1 += (double)W * u1[k] + cw[k] * s1[k];
        }
        for (Py_ssize_t i = Bv; i < B; i++) {
            double d = p[i + 1] - p[i], e = y[i + 1] - y[i];
            W0 += (double)(B - i) * d;
            W1 += (double)(B - i) * e;
            double hi = d > e ? d : e, lo = d < e ? d : e;
            mx[0] = hi > mx[0] ? hi : mx[0];
            mn[0] = lo < mn[0] ? lo : mn[0];
            nan[0] |= (d != d) | (e != e);
        }
        w_out[b] = W0;
        w_out[b + 1] = W1;
    }
    if (b < nb) {               /* the last block of an odd count: the same lanes alone */
        const double *p = enc + b * B;
        double s0[W] = {0}, u0[W] = {0}, W0 = 0;
        for (Py_ssize_t r = 0; r < R; r++) {
            const double *q = p + r * W;
            for (int k = 0; k < W; k++) {
                double d = q[k + 1] - q[k];
                s0[k] += d;
                u0[k] += s0[k];
                mx[k] = d > mx[k] ? d : mx[k];
                mn[k] = d < mn[k] ? d : mn[k];
                nan[k] |= d != d;
            }
        }
        for (int k = 0; k < W; k++)
            W0 += (double)W * u0[k] + cw[k] * s0[k];
        for (Py_ssize_t i = Bv; i < B; i++) {
            double d = p[i + 1] - p[i];
            W0 += (double)(B - i) * d;
            mx[0] = d > mx[0] ? d : mx[0];
            mn[0] = d < mn[0] ? d : mn[0];
            nan[0] |= d != d;
        }
        w_out[b] = W0;
    }
    for (Py_ssize_t k = nb * B; k < n - 1; k++) {
        double d = enc[k + 1] - enc[k];
        mx[0] = d > mx[0] ? d : mx[0];
        mn[0] = d < mn[0] ? d : mn[0];
        nan[0] |= d != d;
    }
    double M = mx[0], m = mn[0];
    int any_nan = nan[0];
    for (int k = 1; k < W; k++) {
        M = mx[k] > M ? mx[k] : M;
        m = mn[k] < m ? mn[k] : m;
        any_nan |= nan[k];
    }
    *largest = any_nan ? NAN : M;
    *smallest = any_nan ? NAN : m;
}

/* cos and sin of small angles d by the series of hse_opt/align/blocks.py's _cos_sin_small, in
   its order for `order` (2: to 1e-3, 4: to 0.03, 6: to 0.2; 0: libm's), and sin(d) / d (1 at 0)
   when `sinc` is given */
static inline void
small_cos_sin(double d, int order, double *c, double *s, double *sinc)
{
    const double q = d * d;
    double cd, f;
    if (order == 2) {
        cd = q * -0.5 + 1.0;
        f = q * (-1.0 / 6.0) + 1.0;
    } else if (order == 4) {
        cd = (q * (1.0 / 24.0) - 0.5) * q + 1.0;
        f = (q * (1.0 / 120.0) - 1.0 / 6.0) * q + 1.0;
    } else if (order == 6) {
        cd = 1.0 - q * (0.5 - q * (1.0 / 24.0 - q / 720.0));
        f = 1.0 - q * (1.0 / 6.0 - q / 120.0);
    } else {
        *c = cos(d);
        *s = sin(d);
        if (sinc)
            *sinc = d != 0.0 ? *s / d : 1.0;
        return;
    }
    *c = cd;
    *s = f * d;
    if (sinc)
        *sinc = f;
}

/* the series' order for the largest |d| (NaN: libm's) */
static inline int
series_order(double top, int nan)
{
    return nan || !(top <= 0.2) ? 0 : top <= 1e-3 ? 2 : top <= 0.03 ? 4 : 6;
}

/* The Allan analysis' clusters shorter than a block (hse_opt/align/noise.py, _short_allan): in
   each of `count` stretches of L increments starting after sample first[j] (a block edge), the
   fitted deterministic part taken off every increment of the six channels - its angle by the
   series of the deviation from the block edge's angle (the order numpy's route picks from the
   largest deviation of all stretches) and the angle-addition formulas - then, for each size m
   (powers of two, ascending), the sum over the stretch of the squared differences of two
   adjacent sums of m increments (the sums by doubling, as numpy's route takes them).
   work: scratch of count L + 6 L values. */
CLONES static void
short_squares(const double *const x[6], const double *enc, const double *t, const long long *first,
              Py_ssize_t count, Py_ssize_t L, Py_ssize_t block, const double *coef, double rate,
              const double *ec, const double *es, const Py_ssize_t *sizes, Py_ssize_t k, double *ss,
              double *work)
{
    double *mid = work, *X0 = work + count * L, *X1 = X0 + L, *X2 = X1 + L, *X3 = X2 + L;
    double *r = X3 + L, *v = r + L;
    double top = 0.0;
    int nan = 0;
    for (Py_ssize_t j = 0; j < count; j++) {
        const Py_ssize_t s0 = (Py_ssize_t)first[j];
        for (Py_ssize_t l0 = 0; l0 < L; l0 += block) {
            const double edge = enc[s0 + l0];
            const Py_ssize_t l1 = l0 + block < L ? l0 + block : L;
            for (Py_ssize_t l = l0; l < l1; l++) {
                const Py_ssize_t i = s0 + 1 + l;
                const double d = ((enc[i] - enc[i - 1]) * 0.5 + enc[i - 1]) - edge;
                mid[j * L + l] = d;
                const double a = fabs(d);
                top = a > top ? a : top;
                nan |= d != d;
            }
        }
    }
    const int order = series_order(top, nan);
    for (Py_ssize_t j = 0; j < count; j++) {
        const Py_ssize_t s0 = (Py_ssize_t)first[j];
        const double *d = mid + j * L;
        for (Py_ssize_t l = 0; l < L; l++)          /* cos and sin of the deviations into X1, X2 */
            small_cos_sin(d[l], order, &X1[l], &X2[l], NULL);
        /* the four regressors of each increment: dt, cos dt, sin dt, d alpha - rate dt */
        for (Py_ssize_t l0 = 0; l0 < L; l0 += block) {
            const Py_ssize_t b = s0 / block + l0 / block, l1 = l0 + block < L ? l0 + block : L;
            const double ce = ec[b], se = es[b];
            for (Py_ssize_t l = l0; l < l1; l++) {
                const Py_ssize_t i = s0 + 1 + l;
                const double h = t[i] - t[i - 1], cd = X1[l], sd = X2[l];
                X0[l] = h;
                X1[l] = (ce * cd - se * sd) * h;
                X2[l] = (se * cd + ce * sd) * h;
                X3[l] = (enc[i] - enc[i - 1]) - rate * h;
            }
        }
        for (int c = 0; c < 6; c++) {
            const double c0 = coef[c], c1 = coef[6 + c], c2 = coef[12 + c], c3 = coef[18 + c];
            const double *xc = x[c] + s0 + 1;
            for (Py_ssize_t l = 0; l < L; l++)
                r[l] = xc[l] - (((c0 * X0[l] + c1 * X1[l]) + c2 * X2[l]) + c3 * X3[l]);
            /* the sums of m increments by doubling (r and v in turn; entries i <= L - width are
               sums within the stretch), the squared differences of adjacent ones */
            Py_ssize_t width = 1;
            double *cur = r, *nxt = v;
            for (Py_ssize_t z = 0; z < k; z++) {
                const Py_ssize_t m = sizes[z];
                while (width < m) {
                    const Py_ssize_t len = L - 2 * width + 1;
                    for (Py_ssize_t i = 0; i < len; i++)
                        nxt[i] = cur[i] + cur[i + width];
                    double *tmp = cur;
                    cur = nxt;
                    nxt = tmp;
                    width *= 2;
                }
                double acc[4] = {0, 0, 0, 0};
                const Py_ssize_t nd = L - 2 * m + 1;
                Py_ssize_t i = 0;
                for (; i + 4 <= nd; i += 4)
                    for (int u = 0; u < 4; u++) {
                        const double e = cur[i + u + m] - cur[i + u];
                        acc[u] += e * e;
                    }
                for (; i < nd; i++) {
                    const double e = cur[i + m] - cur[i];
                    acc[0] += e * e;
                }
                ss[(c * count + j) * k + z] = (acc[0] + acc[1]) + (acc[2] + acc[3]);
            }
        }
    }
}

/* The quantum of a row x (N values; hse_opt/align/_quanta.py, _row_quanta): the smallest change
   between consecutive values above 1e-9 of the row's mean magnitude, 0 when no more than
   `changes` of them are above it (NaN when a change is NaN). */
static double
row_quantum(const double *x, Py_ssize_t N, Py_ssize_t changes)
{
    if (N < 2)
        return 0.0;
    double mag = 0.0;
    for (Py_ssize_t i = 0; i < N; i++)
        mag += fabs(x[i]);
    const double floor = 1e-9 * (mag / (double)N);
    double least = INFINITY;
    Py_ssize_t seen = 0;
    int nan = 0;
    for (Py_ssize_t i = 1; i < N; i++) {
        const double d = fabs(x[i] - x[i - 1]);
        if (!(d <= floor)) {            /* a change (a NaN too, as numpy's comparison) */
            seen++;
            nan |= d != d;
            least = d < least ? d : least;
        }
    }
    if (seen <= changes)
        return 0.0;
    return nan ? NAN : least;
}

#define PHASE_TABLE 64

/* The deterministic part's regressors of hse_opt/align/blocks.py's _fit_residual for nb blocks
   of B samples (module docstring, step 2), and the normal equations of its fit: the encoder
   angle at the block edges' cos and sin (ce, se: nb + 1; its linear phase from two tables of
   PHASE_TABLE steps, the deviation by series, as _cos_sin), the regressors X (4, nb), G = X X^T
   (4, 4) and H = X y^T (4, 6) of the block sums y (6, nb). Returns the encoder's mean rate.
   The edges are gathered first (one strided read of the record each; every later pass reads
   them in place). work: scratch of 3 (nb + 1) + 2 PHASE_TABLE values. */
CLONES static double
fit_blocks(const double *enc, const double *t, Py_ssize_t B, Py_ssize_t nb, const double *y, double *ce,
           double *se, double *X, double *G, double *H, double *work)
{
    const Py_ssize_t n = nb + 1;
    double *a = work, *te = work + n, *d = te + n, *lr = d + n, *li = lr + PHASE_TABLE;
    for (Py_ssize_t i = 0; i < n; i++) {
        a[i] = enc[i * B];
        te[i] = t[i * B];
    }
    const double a0 = a[0], rate = (a[nb] - a0) / (te[nb] - te[0]);
    const double step = (a[nb] - a0) / (double)(n - 1 > 1 ? n - 1 : 1);
    double top = 0.0;
    int nan = 0;
    for (Py_ssize_t i = 0; i < n; i++) {
        d[i] = a[i] - (a0 + step * (double)i);
        const double m = fabs(d[i]);
        top = m > top ? m : top;
        nan |= d[i] != d[i];
    }
    if (nan || !(top <= 0.2)) {
        for (Py_ssize_t i = 0; i < n; i++) {
            ce[i] = cos(a[i]);
            se[i] = sin(a[i]);
        }
    } else {
        const int order = series_order(top, 0);
        for (int l = 0; l < PHASE_TABLE; l++) {
            lr[l] = cos(step * (double)l);
            li[l] = sin(step * (double)l);
        }
        for (Py_ssize_t j0 = 0; j0 < n; j0 += PHASE_TABLE) {
            const double ph = a0 + (double)PHASE_TABLE * step * (double)(j0 / PHASE_TABLE);
            const double hr = cos(ph), hi = sin(ph);
            const Py_ssize_t j1 = j0 + PHASE_TABLE < n ? j0 + PHASE_TABLE : n;
            for (Py_ssize_t i = j0; i < j1; i++) {
                const double pr = hr * lr[i - j0] - hi * li[i - j0], pi = hr * li[i - j0] + hi * lr[i - j0];
                double cd, sd;
                small_cos_sin(d[i], order, &cd, &sd, NULL);
                ce[i] = pr * cd - pi * sd;
                se[i] = pi * cd + pr * sd;
            }
        }
    }
    /* the regressors: dt, cos and sin at the block's mid angle times sinc(d alpha / 2) dt,
       d alpha - rate dt (the half turn's cos, sin and sinc by series of its own order) */
    double *X0 = X, *X1 = X + nb, *X2 = X1 + nb, *X3 = X2 + nb;
    top = 0.0;
    nan = 0;
    for (Py_ssize_t b = 0; b < nb; b++) {
        const double h = 0.5 * (a[b + 1] - a[b]), m = fabs(h);
        top = m > top ? m : top;
        nan |= h != h;
    }
    const int order = series_order(top, nan);
    for (Py_ssize_t b = 0; b < nb; b++) {
        const double da = a[b + 1] - a[b], dt = te[b + 1] - te[b];
        double ch, sh, w;
        small_cos_sin(0.5 * da, order, &ch, &sh, &w);
        w *= dt;
        X0[b] = dt;
        X1[b] = (ce[b] * ch - se[b] * sh) * w;
        X2[b] = (se[b] * ch + ce[b] * sh) * w;
        X3[b] = dt * -rate + da;
    }
    for (int i = 0; i < 4; i++) {
        for (int j = 0; j < 4 + 6; j++) {
            if (j < 4 && j > i)
                continue;
            const double *u = X + i * nb, *v = j < 4 ? X + j * nb : y + (j - 4) * nb;
            double acc[4] = {0, 0, 0, 0};
            Py_ssize_t b = 0;
            for (; b + 4 <= nb; b += 4)
                for (int k = 0; k < 4; k++)
                    acc[k] += u[b + k] * v[b + k];
            for (; b < nb; b++)
                acc[0] += u[b] * v[b];
            const double dot = (acc[0] + acc[1]) + (acc[2] + acc[3]);
            if (j < 4)
                G[i * 4 + j] = G[j * 4 + i] = dot;
            else
                H[i * 6 + j - 4] = dot;
        }
    }
    return rate;
}

/* out = y - coef^T X: y (6, nb), coef (4, 6), X (4, nb) */
CLONES static void
fit_residual(const double *y, const double *coef, const double *X, Py_ssize_t nb, double *out)
{
    for (int c = 0; c < 6; c++) {
        const double c0 = coef[c], c1 = coef[6 + c], c2 = coef[12 + c], c3 = coef[18 + c];
        const double *yc = y + c * nb;
        double *oc = out + c * nb;
        for (Py_ssize_t b = 0; b < nb; b++)
            oc[b] = yc[b] - (((c0 * X[b] + c1 * X[nb + b]) + c2 * X[2 * nb + b]) + c3 * X[3 * nb + b]);
    }
}

/* Check 3b's statistic D before its slow part is fitted out (hse_opt/align/steps.py,
   step_statistic and weighted_regressors, the same steps): for each gyro j, the residual's
   block sums with the encoder's steps taken off in the ratio beta_j, r = R_j + (coef3_j -
   beta_j) X3; the block sums of the cumulative residual over GRID (4) blocks after each
   block edge less over the 4 before, from r's moving sums and the weighted sums' residual
   rw = Wg_j - C_j . Xw (Xw the regressors summed with the weights, C_j the coefficients with
   beta_j for the jitter and the first three halved); D = that over K = 4 h.
   R (3 rows of nb, row stride rs), coef (4, 6), beta (3), X (4, nb), Wg (3, nb), E (nb);
   D (3, nb - 7); work: 6 nb values. */
static void
step_stat(const double *R, Py_ssize_t rs, const double *coef, const double *beta, const double *X,
          const double *Wg, const double *E, Py_ssize_t nb, Py_ssize_t h, double rate, double *D, double *work)
{
    const double half = 0.5 * (double)(h + 1), hd = (double)h;
    /* (a block of one increment: its weighted sum is its sum, the correction c is 0) */
    const double k1 = (hd * hd - 1.0) / (12.0 * hd * half);
    const double k2 = h > 1 ? ((hd * hd + 1.0) / (60.0 * hd * hd)) / (k1 * k1) : 0.0;
    const double *X0 = X, *X1 = X + nb, *X2 = X1 + nb, *X3 = X2 + nb;
    double *Xw1 = work, *Xw2 = work + nb, *Xw3 = Xw2 + nb, *r = Xw3 + nb, *rw = r + nb, *y = rw + nb;
    /* weighted_regressors: the first three rows divided by (h + 1) / 2 (row 0 is X0 itself) */
    for (Py_ssize_t b = 0; b < nb; b++) {
        double d = X0[b] * (rate * k1);
        d += X3[b] * k1;
        double c = d * d;
        c *= k2;
        c += 1.0;
        c *= d;
        Xw1[b] = c * X2[b] + X1[b];
        Xw2[b] = X2[b] - c * X1[b];
        Xw3[b] = X0[b] * half * -rate + E[b];
    }
    const Py_ssize_t g = nb - 7;
    for (int j = 0; j < 3; j++) {
        const double *Rj = R + j * rs, *Wj = Wg + j * nb;
        const double a = coef[18 + j] - beta[j];
        const double C0 = coef[j] * half, C1 = coef[6 + j] * half, C2 = coef[12 + j] * half, C3 = beta[j];
        for (Py_ssize_t b = 0; b < nb; b++) {
            r[b] = Rj[b] + a * X3[b];
            rw[b] = Wj[b] - (((C0 * X0[b] + C1 * Xw1[b]) + C2 * Xw2[b]) + C3 * Xw3[b]);
        }
        /* y = h (moving sum of r over 4, as _moving's doubling) + rw[b + 4] - rw[b] */
        for (Py_ssize_t b = 0; b < nb - 4; b++) {
            double m = (r[b] + r[b + 1]) + (r[b + 2] + r[b + 3]);
            m *= hd;
            m += rw[b + 4];
            m -= rw[b];
            y[b] = m;
        }
        double *Dj = D + j * g;
        const double K = 4.0 * hd;
        for (Py_ssize_t b = 0; b < g; b++)
            Dj[b] = ((y[b] + y[b + 1]) + (y[b + 2] + y[b + 3])) / K;
    }
}

/* The overlapping Allan analysis' squared second differences on an octave plan
   (hse_opt/align/noise.py, _octave_squares, the same sums): for one row x of n block sums and
   each cluster (m, step, cnt) of the plan, the sum over the start points k = 0, step, ..
   (cnt of them) of (S(k + m, m) - S(k, m))^2, S(i, m) the sum of x[i .. i + m - 1]. Clusters
   shorter than the lattice stride s take S at their own stride (x's sums over m by pairs);
   longer ones, q = m / s lattice sums apart, sums D_q of q consecutive lattice sums S_s by
   doubling (D_2q[j] = D_q[j] + D_q[j + q]). No sum runs over the record.
   work: scratch of 2 n values. */
/* sum over c < cnt of (a[c stride + gap] - a[c stride])^2, in four lanes */
static double
strided_squares(const double *a, Py_ssize_t stride, Py_ssize_t gap, Py_ssize_t cnt)
{
    double acc[4] = {0, 0, 0, 0};
    Py_ssize_t c = 0;
    for (; c + 4 <= cnt; c += 4)
        for (int u = 0; u < 4; u++) {
            const double e = a[(c + u) * stride + gap] - a[(c + u) * stride];
            acc[u] += e * e;
        }
    for (; c < cnt; c++) {
        const double e = a[c * stride + gap] - a[c * stride];
        acc[0] += e * e;
    }
    return (acc[0] + acc[1]) + (acc[2] + acc[3]);
}

static void
octave_row(const double *x, Py_ssize_t n, const Py_ssize_t *plan, Py_ssize_t k, Py_ssize_t s, double *ss,
           Py_ssize_t ss_stride, double *work)
{
    double *next = work, *lat = work + n;  /* next: the levels S_w, w < s, one after another */
    const double *S = x;                   /* S_w at stride w, n / w entries */
    Py_ssize_t w = 1, len = n, z = 0;
    /* the clusters shorter than the lattice (m < s, in the plan's order), then the lattice */
    for (;; z++) {
        if (z == k)
            return;
        const int lattice = plan[3 * z] >= s;
        const Py_ssize_t m = lattice ? s : plan[3 * z];
        while (w < m) {
            const Py_ssize_t half = len / 2;
            for (Py_ssize_t i = 0; i < half; i++)
                next[i] = S[2 * i] + S[2 * i + 1];
            S = next;
            next += half;
            len = half;
            w *= 2;
        }
        if (lattice)
            break;
        ss[z * ss_stride] = strided_squares(S, plan[3 * z + 1] / m, 1, plan[3 * z + 2]);
    }
    const Py_ssize_t nl = n / s;           /* the lattice sums S_s */
    for (Py_ssize_t i = 0; i < nl; i++)
        lat[i] = S[i];
    Py_ssize_t q = 1, size = nl;           /* D_q: entries 0 .. size - 1 */
    for (; z < k; z++) {
        while (q < plan[3 * z] / s) {
            for (Py_ssize_t j = 0; j + q < size; j++)
                lat[j] += lat[j + q];
            size -= q;
            q *= 2;
        }
        ss[z * ss_stride] = strided_squares(lat, 1, q, plan[3 * z + 2]);
    }
}

/* a C-contiguous float64 buffer of at least `need` elements (exactly `need` when `exact`),
   writable when asked */
static int
doubles(PyObject *obj, Py_buffer *view, int writable, Py_ssize_t need, int exact, const char *name)
{
    int flags = PyBUF_FORMAT | PyBUF_C_CONTIGUOUS | (writable ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(obj, view, flags) < 0)
        return -1;
    if (view->itemsize != 8 || view->format == NULL || strcmp(view->format, "d") != 0) {
        PyErr_Format(PyExc_TypeError, "%s: a contiguous float64 array is needed", name);
        PyBuffer_Release(view);
        return -1;
    }
    if (exact ? view->len / 8 != need : view->len / 8 < need) {
        PyErr_Format(PyExc_ValueError, "%s: %zd values, %s %zd needed", name, view->len / 8,
                     exact ? "exactly" : "at least", need);
        PyBuffer_Release(view);
        return -1;
    }
    return 0;
}

/* doubles() for each of k objects in turn, writable from index `writable` on, of exactly their
   `need` from index `exact` on; returns how many it took (k when all; else the error is set) */
static int
take_doubles(PyObject *const *objs, Py_buffer *v, int k, const Py_ssize_t *need, int writable, int exact,
             const char *const *names)
{
    int i = 0;
    while (i < k && doubles(objs[i], &v[i], i >= writable, need[i], i >= exact, names[i]) == 0)
        i++;
    return i;
}

static void
release_doubles(Py_buffer *v, int held)
{
    for (int i = 0; i < held; i++)
        PyBuffer_Release(&v[i]);
}

/* whether nb blocks of B samples (and one more sample) can be counted in bytes */
static int
countable(Py_ssize_t B, Py_ssize_t nb, const char *name)
{
    if (B < 1 || nb < 0 || nb > (PY_SSIZE_T_MAX / 8 - 1) / B) {
        PyErr_Format(PyExc_ValueError, "%s: block >= 1 and 0 <= nb <= %zd are needed", name,
                     B < 1 ? (Py_ssize_t)0 : (PY_SSIZE_T_MAX / 8 - 1) / B);
        return 0;
    }
    return 1;
}

PyDoc_STRVAR(block_sums_doc,
"block_sums(x, block, nb, sums, weighted=None)\n--\n\n"
"Sums of x[1 + b block .. (b + 1) block] for b < nb into sums (nb,) and, when given,\n"
"their weighted sums (increment i of a block weighted block + 1 - i) into weighted (nb,).\n"
"x: a contiguous float64 array of at least nb block + 1 values.");

static PyObject *
block_sums(PyObject *self, PyObject *args)
{
    PyObject *xo, *so, *wo = Py_None;
    Py_ssize_t B, nb;
    if (!PyArg_ParseTuple(args, "OnnO|O:block_sums", &xo, &B, &nb, &so, &wo))
        return NULL;
    if (!countable(B, nb, "block_sums"))
        return NULL;
    Py_buffer x, s, w;
    if (doubles(xo, &x, 0, nb * B + 1, 0, "x") < 0)
        return NULL;
    if (doubles(so, &s, 1, nb, 0, "sums") < 0) {
        PyBuffer_Release(&x);
        return NULL;
    }
    int weighted = wo != Py_None;
    if (weighted && doubles(wo, &w, 1, nb, 0, "weighted") < 0) {
        PyBuffer_Release(&x);
        PyBuffer_Release(&s);
        return NULL;
    }
    Py_BEGIN_ALLOW_THREADS
    channel_blocks((const double *)x.buf, B, nb, (double *)s.buf, weighted ? (double *)w.buf : NULL);
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&x);
    PyBuffer_Release(&s);
    if (weighted)
        PyBuffer_Release(&w);
    Py_RETURN_NONE;
}

PyDoc_STRVAR(encoder_steps_doc,
"encoder_steps(enc, block, nb, weighted) -> (largest, smallest)\n--\n\n"
"The weighted sums of the steps enc[k + 1] - enc[k] over blocks of block steps (step\n"
"b block + i weighted block - i) into weighted (nb,), and the largest and the smallest of\n"
"all len(enc) - 1 steps (NaN when a step is NaN). enc: a contiguous float64 array of at\n"
"least nb block + 1 values and at least 2.");

static PyObject *
encoder_steps(PyObject *self, PyObject *args)
{
    PyObject *eo, *wo;
    Py_ssize_t B, nb;
    if (!PyArg_ParseTuple(args, "OnnO:encoder_steps", &eo, &B, &nb, &wo))
        return NULL;
    if (!countable(B, nb, "encoder_steps"))
        return NULL;
    Py_buffer e, w;
    Py_ssize_t need = nb * B + 1 > 2 ? nb * B + 1 : 2;
    if (doubles(eo, &e, 0, need, 0, "enc") < 0)
        return NULL;
    if (doubles(wo, &w, 1, nb, 0, "weighted") < 0) {
        PyBuffer_Release(&e);
        return NULL;
    }
    double largest, smallest;
    Py_BEGIN_ALLOW_THREADS
    encoder_blocks((const double *)e.buf, e.len / 8, B, nb, (double *)w.buf, &largest, &smallest);
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&e);
    PyBuffer_Release(&w);
    return Py_BuildValue("dd", largest, smallest);
}

PyDoc_STRVAR(short_allan_doc,
"short_allan(channels, enc, t, first, length, block, coef, rate, edge_cos, edge_sin, sizes, ss)\n--\n\n"
"The squared differences of the Allan analysis' clusters shorter than a block (noise.py's\n"
"_short_allan) into ss (6, count, len(sizes)): channels, six contiguous float64 rows (n,);\n"
"enc, t (n,); first (count,) int64 stretch starts (block edges); coef (4, 6) the fitted\n"
"coefficients; edge_cos, edge_sin the block edges' cos and sin; sizes ascending powers of two.");

static PyObject *
short_allan(PyObject *self, PyObject *args)
{
    PyObject *cho, *eo, *to, *fo, *co, *eco, *eso, *so, *sso;
    Py_ssize_t L, block;
    double rate;
    if (!PyArg_ParseTuple(args, "OOOOnnOdOOOO:short_allan", &cho, &eo, &to, &fo, &L, &block, &co, &rate, &eco,
                          &eso, &so, &sso))
        return NULL;
    PyObject *seq = PySequence_Fast(cho, "short_allan: channels must be a sequence of six arrays");
    if (seq == NULL)
        return NULL;
    PyObject *sizes_seq = PySequence_Fast(so, "short_allan: sizes must be a sequence of ints");
    if (sizes_seq == NULL) {
        Py_DECREF(seq);
        return NULL;
    }
    /* v: first, enc, t, coef, edge_cos, edge_sin, ss, then the six channels; held of them */
    Py_buffer v[13];
    int held = 0, ok = 0;
    Py_ssize_t count = 0, k = PySequence_Fast_GET_SIZE(sizes_seq);
    Py_ssize_t *sizes = NULL;
    double *work = NULL;
    if (PySequence_Fast_GET_SIZE(seq) != 6) {
        PyErr_SetString(PyExc_ValueError, "short_allan: six channels are needed");
        goto done;
    }
    if (L < 2 || block < 1 || k < 1) {
        PyErr_SetString(PyExc_ValueError, "short_allan: length >= 2, block >= 1 and one size at least are needed");
        goto done;
    }
    sizes = PyMem_Malloc(k * sizeof(Py_ssize_t));
    if (sizes == NULL) {
        PyErr_NoMemory();
        goto done;
    }
    for (Py_ssize_t z = 0; z < k; z++) {
        sizes[z] = PyLong_AsSsize_t(PySequence_Fast_GET_ITEM(sizes_seq, z));
        if (sizes[z] == -1 && PyErr_Occurred())
            goto done;
        if (sizes[z] < 1 || (sizes[z] & (sizes[z] - 1)) || (z && sizes[z] < sizes[z - 1]) || sizes[z] > L / 2) {
            PyErr_SetString(PyExc_ValueError, "short_allan: sizes must be powers of two, not decreasing, with 2 m <= "
                            "length");
            goto done;
        }
    }
    if (PyObject_GetBuffer(fo, &v[0], PyBUF_FORMAT | PyBUF_C_CONTIGUOUS) < 0)
        goto done;
    held = 1;
    if (v[0].itemsize != 8 || v[0].format == NULL || (strcmp(v[0].format, "q") != 0 && strcmp(v[0].format, "l") != 0)) {
        PyErr_SetString(PyExc_TypeError, "short_allan: first must be a contiguous int64 array");
        goto done;
    }
    count = v[0].len / 8;
    const long long *first = (const long long *)v[0].buf;
    if (doubles(eo, &v[1], 0, 2, 0, "enc") < 0)
        goto done;
    held = 2;
    const Py_ssize_t n = v[1].len / 8;
    for (Py_ssize_t j = 0; j < count; j++)
        if (first[j] < 0 || first[j] % block || first[j] > n - 1 - L) {
            PyErr_SetString(PyExc_ValueError, "short_allan: a stretch starts off a block edge or runs past the log");
            goto done;
        }
    PyObject *objs[5] = {to, co, eco, eso, sso};
    const Py_ssize_t need[5] = {n, 24, 1, 0, 6 * count * k};
    const char *names[5] = {"t", "coef", "edge_cos", "edge_sin", "ss"};
    for (int i = 0; i < 5; i++, held++) {
        const Py_ssize_t want = i == 3 ? v[4].len / 8 : need[i];       /* edge_sin: as long as edge_cos */
        if (doubles(objs[i], &v[2 + i], i == 4, want, i != 0 && i != 2, names[i]) < 0)
            goto done;
    }
    for (Py_ssize_t j = 0; j < count; j++)
        if (first[j] / block + (L - 1) / block >= v[4].len / 8) {
            PyErr_SetString(PyExc_ValueError, "short_allan: edge_cos and edge_sin do not reach the stretches' blocks");
            goto done;
        }
    const double *rows[6];
    for (int i = 0; i < 6; i++, held++) {
        if (doubles(PySequence_Fast_GET_ITEM(seq, i), &v[7 + i], 0, n, 0, "channels") < 0)
            goto done;
        rows[i] = (const double *)v[7 + i].buf;
    }
    work = PyMem_Malloc((count * L + 6 * L) * sizeof(double));
    if (work == NULL) {
        PyErr_NoMemory();
        goto done;
    }
    Py_BEGIN_ALLOW_THREADS
    short_squares(rows, (const double *)v[1].buf, (const double *)v[2].buf, first, count, L, block,
                  (const double *)v[3].buf, rate, (const double *)v[4].buf, (const double *)v[5].buf, sizes, k,
                  (double *)v[6].buf, work);
    Py_END_ALLOW_THREADS
    ok = 1;
done:
    release_doubles(v, held);
    PyMem_Free(work);
    PyMem_Free(sizes);
    Py_DECREF(sizes_seq);
    Py_DECREF(seq);
    if (!ok)
        return NULL;
    Py_RETURN_NONE;
}

PyDoc_STRVAR(quanta_doc,
"quanta(rows, changes) -> tuple of float\n--\n\n"
"The quantum of each row (contiguous float64 arrays): the smallest change between consecutive\n"
"values above 1e-9 of the row's mean magnitude, 0 when no more than `changes` are above it.");

static PyObject *
quanta(PyObject *self, PyObject *args)
{
    PyObject *ro;
    Py_ssize_t changes;
    if (!PyArg_ParseTuple(args, "On:quanta", &ro, &changes))
        return NULL;
    PyObject *seq = PySequence_Fast(ro, "quanta: rows must be a sequence of arrays");
    if (seq == NULL)
        return NULL;
    const Py_ssize_t k = PySequence_Fast_GET_SIZE(seq);
    PyObject *out = PyTuple_New(k);
    for (Py_ssize_t j = 0; out != NULL && j < k; j++) {
        Py_buffer v;
        if (doubles(PySequence_Fast_GET_ITEM(seq, j), &v, 0, 0, 0, "rows") < 0) {
            Py_CLEAR(out);
            break;
        }
        const double q = row_quantum((const double *)v.buf, v.len / 8, changes);
        PyBuffer_Release(&v);
        PyObject *f = PyFloat_FromDouble(q);
        if (f == NULL) {
            Py_CLEAR(out);
            break;
        }
        PyTuple_SET_ITEM(out, j, f);
    }
    Py_DECREF(seq);
    return out;
}

PyDoc_STRVAR(fit_doc,
"fit(enc, t, block, nb, y, edge_cos, edge_sin, X, G, H) -> rate\n--\n\n"
"The deterministic part's regressors and normal equations (blocks.py's _fit_residual) of the\n"
"block sums y (6, nb) over blocks of `block` samples: cos and sin of the encoder at the block\n"
"edges into edge_cos, edge_sin (nb + 1,), the regressors into X (4, nb), X X^T into G (4, 4)\n"
"and X y^T into H (4, 6); returns the encoder's mean rate.");

static PyObject *
fit(PyObject *self, PyObject *args)
{
    PyObject *eo, *to, *yo, *ceo, *seo, *xo, *go, *ho;
    Py_ssize_t B, nb;
    if (!PyArg_ParseTuple(args, "OOnnOOOOOO:fit", &eo, &to, &B, &nb, &yo, &ceo, &seo, &xo, &go, &ho))
        return NULL;
    if (!countable(B, nb, "fit"))
        return NULL;
    if (nb < 1) {
        PyErr_SetString(PyExc_ValueError, "fit: nb >= 1 is needed");
        return NULL;
    }
    PyObject *objs[8] = {eo, to, yo, ceo, seo, xo, go, ho};
    const Py_ssize_t need[8] = {nb * B + 1, nb * B + 1, 6 * nb, nb + 1, nb + 1, 4 * nb, 16, 24};
    const char *names[8] = {"enc", "t", "y", "edge_cos", "edge_sin", "X", "G", "H"};
    Py_buffer v[8];
    double rate = 0.0, *work = NULL;
    const int held = take_doubles(objs, v, 8, need, 3, 2, names);
    if (held < 8)
        goto done;
    work = PyMem_Malloc((3 * (nb + 1) + 2 * PHASE_TABLE) * sizeof(double));
    if (work == NULL) {
        PyErr_NoMemory();
        goto done;
    }
    Py_BEGIN_ALLOW_THREADS
    rate = fit_blocks((const double *)v[0].buf, (const double *)v[1].buf, B, nb, (const double *)v[2].buf,
                      (double *)v[3].buf, (double *)v[4].buf, (double *)v[5].buf, (double *)v[6].buf,
                      (double *)v[7].buf, work);
    Py_END_ALLOW_THREADS
done:
    release_doubles(v, held);
    PyMem_Free(work);
    if (held < 8 || work == NULL)
        return NULL;
    return PyFloat_FromDouble(rate);
}

PyDoc_STRVAR(residual_doc,
"residual(y, coef, X, out)\n--\n\n"
"out = y - coef^T X: y and out (6, nb), coef (4, 6), X (4, nb), contiguous float64.");

static PyObject *
residual(PyObject *self, PyObject *args)
{
    PyObject *yo, *co, *xo, *oo;
    if (!PyArg_ParseTuple(args, "OOOO:residual", &yo, &co, &xo, &oo))
        return NULL;
    Py_buffer v[4];                       /* y, coef, X, out */
    if (doubles(yo, &v[0], 0, 6, 0, "y") < 0)
        return NULL;
    const Py_ssize_t nb = v[0].len / 8 / 6;
    if (v[0].len / 8 != 6 * nb) {
        PyErr_SetString(PyExc_ValueError, "y: six rows of block sums are needed");
        PyBuffer_Release(&v[0]);
        return NULL;
    }
    PyObject *const objs[3] = {co, xo, oo};
    const Py_ssize_t need[3] = {24, 4 * nb, 6 * nb};
    const char *const names[3] = {"coef", "X", "out"};
    const int held = 1 + take_doubles(objs, v + 1, 3, need, 2, 0, names);
    if (held == 4) {
        Py_BEGIN_ALLOW_THREADS
        fit_residual((const double *)v[0].buf, (const double *)v[1].buf, (const double *)v[2].buf, nb,
                     (double *)v[3].buf);
        Py_END_ALLOW_THREADS
    }
    release_doubles(v, held);
    if (held < 4)
        return NULL;
    Py_RETURN_NONE;
}

PyDoc_STRVAR(step_statistic_doc,
"step_statistic(R, coef, beta, X, W, E, h, rate, D)\n--\n\n"
"Check 3b's statistic before its slow part is fitted out (steps.py's step_statistic) into\n"
"D (3, nb - 7): R (3, nb) the gyros' residual block sums, coef (4, 6), beta (3,), X (4, nb)\n"
"the regressors, W (3, nb) the gyros' weighted sums, E (nb,) the encoder's, h the block.");

static PyObject *
step_statistic(PyObject *self, PyObject *args)
{
    PyObject *objs[7];
    Py_ssize_t h;
    double rate;
    if (!PyArg_ParseTuple(args, "OOOOOOndO:step_statistic", &objs[0], &objs[1], &objs[2], &objs[3], &objs[4],
                          &objs[5], &h, &rate, &objs[6]))
        return NULL;
    Py_buffer v[7];
    int held = 0;
    double *work = NULL;
    if (doubles(objs[5], &v[5], 0, 8, 0, "E") < 0)
        return NULL;
    const Py_ssize_t nb = v[5].len / 8;
    PyBuffer_Release(&v[5]);
    const Py_ssize_t need[7] = {3 * nb, 24, 3, 4 * nb, 3 * nb, nb, 3 * (nb - 7)};
    const char *names[7] = {"R", "coef", "beta", "X", "W", "E", "D"};
    if (h < 1) {
        PyErr_SetString(PyExc_ValueError, "step_statistic: h >= 1 is needed");
        return NULL;
    }
    held = take_doubles(objs, v, 7, need, 6, 0, names);
    if (held < 7)
        goto done;
    work = PyMem_Malloc(6 * nb * sizeof(double));
    if (work == NULL) {
        PyErr_NoMemory();
        goto done;
    }
    Py_BEGIN_ALLOW_THREADS
    step_stat((const double *)v[0].buf, nb, (const double *)v[1].buf, (const double *)v[2].buf,
              (const double *)v[3].buf, (const double *)v[4].buf, (const double *)v[5].buf, nb, h, rate,
              (double *)v[6].buf, work);
    Py_END_ALLOW_THREADS
done:
    release_doubles(v, held);
    PyMem_Free(work);
    if (held < 7 || work == NULL)
        return NULL;
    Py_RETURN_NONE;
}

PyDoc_STRVAR(octave_squares_doc,
"octave_squares(x, plan, s, ss)\n--\n\n"
"noise.py's _octave_squares: x (c, n) block sums, plan a sequence of (m, step, count) with the\n"
"sizes powers of two (ascending) and those below the lattice stride s dividing their step;\n"
"the sums of squared second differences into ss (k, c).");

static PyObject *
octave_squares(PyObject *self, PyObject *args)
{
    PyObject *xo, *po, *so;
    Py_ssize_t s;
    if (!PyArg_ParseTuple(args, "OOnO:octave_squares", &xo, &po, &s, &so))
        return NULL;
    PyObject *seq = PySequence_Fast(po, "octave_squares: plan must be a sequence of (m, step, count)");
    if (seq == NULL)
        return NULL;
    const Py_ssize_t k = PySequence_Fast_GET_SIZE(seq);
    Py_ssize_t *plan = PyMem_Malloc((3 * k + 1) * sizeof(Py_ssize_t));
    double *work = NULL;
    Py_buffer x, out;
    int held = 0, ok = 0;
    if (plan == NULL) {
        PyErr_NoMemory();
        goto done;
    }
    if (doubles(xo, &x, 0, 1, 0, "x") < 0)
        goto done;
    held = 1;
    if (x.ndim != 2) {
        PyErr_SetString(PyExc_ValueError, "octave_squares: x must be (channels, n)");
        goto done;
    }
    const Py_ssize_t c = x.shape[0], n = x.shape[1];
    for (Py_ssize_t z = 0; z < k; z++) {
        PyObject *t = PySequence_Fast(PySequence_Fast_GET_ITEM(seq, z), "octave_squares: a plan entry must be "
                                      "(m, step, count)");
        if (t == NULL)
            goto done;
        int good = PySequence_Fast_GET_SIZE(t) == 3;
        for (int i = 0; good && i < 3; i++) {
            plan[3 * z + i] = PyLong_AsSsize_t(PySequence_Fast_GET_ITEM(t, i));
            good = !(plan[3 * z + i] == -1 && PyErr_Occurred());
        }
        Py_DECREF(t);
        const Py_ssize_t m = good ? plan[3 * z] : 0, step = good ? plan[3 * z + 1] : 0, cnt = good ? plan[3 * z + 2] : 0;
        /* the start points and their clusters lie within the row; the sizes ascend, powers of two */
        good = good && m >= 1 && !(m & (m - 1)) && step >= 1 && cnt >= 1 && (z == 0 || m >= plan[3 * z - 3])
               && m <= n / 2 && cnt - 1 <= (n - 2 * m) / step
               && (m < s ? step % m == 0 : step == s && m % s == 0);
        if (!good) {
            if (!PyErr_Occurred())
                PyErr_SetString(PyExc_ValueError, "octave_squares: a plan entry is no octave cluster within the row");
            goto done;
        }
    }
    if (s < 1 || (s & (s - 1)) || s > n) {
        PyErr_SetString(PyExc_ValueError, "octave_squares: the lattice stride must be a power of two within the row");
        goto done;
    }
    if (doubles(so, &out, 1, k * c, 1, "ss") < 0)
        goto done;
    held = 2;
    work = PyMem_Malloc(2 * n * sizeof(double) + sizeof(double));
    if (work == NULL) {
        PyErr_NoMemory();
        goto done;
    }
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t ch = 0; ch < c; ch++)
        octave_row((const double *)x.buf + ch * n, n, plan, k, s, (double *)out.buf + ch, c, work);
    Py_END_ALLOW_THREADS
    ok = 1;
done:
    if (held >= 2)
        PyBuffer_Release(&out);
    if (held >= 1)
        PyBuffer_Release(&x);
    PyMem_Free(work);
    PyMem_Free(plan);
    Py_DECREF(seq);
    if (!ok)
        return NULL;
    Py_RETURN_NONE;
}

static PyMethodDef methods[] = {
    {"block_sums", block_sums, METH_VARARGS, block_sums_doc},
    {"encoder_steps", encoder_steps, METH_VARARGS, encoder_steps_doc},
    {"short_allan", short_allan, METH_VARARGS, short_allan_doc},
    {"quanta", quanta, METH_VARARGS, quanta_doc},
    {"fit", fit, METH_VARARGS, fit_doc},
    {"residual", residual, METH_VARARGS, residual_doc},
    {"step_statistic", step_statistic, METH_VARARGS, step_statistic_doc},
    {"octave_squares", octave_squares, METH_VARARGS, octave_squares_doc},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_kernels",
    "The raw-log path's passes over a record, compiled (private; hse_opt/align/_kernels.c).",
    -1, methods,
};

PyMODINIT_FUNC
PyInit__kernels(void)
{
    return PyModule_Create(&module);
}
