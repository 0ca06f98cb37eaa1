/* The raw-log path's passes over a record, compiled (hse_opt.align._kernels; private).

   What hse_opt/align/blocks.py takes of a record for the quality checks and the Allan analysis
   in one read of each array, where numpy takes two or three: a channel's sums over blocks of
   B samples with, for a gyro, their weighted sums (increment i of a block weighted B + 1 - i);
   the encoder's steps' weighted sums over the same blocks and the extremes of all its steps.
   The same sums as blocks.py's numpy route to rounding (other summation orders: within a few
   units of the last place of the sums' terms; tests/test_align_kernels.py). Built by setup.py
   where a C compiler is present; without it blocks.py takes numpy's route.

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

/* a C-contiguous float64 buffer of at least `need` elements (writable when asked) */
static int
doubles(PyObject *obj, Py_buffer *view, int writable, Py_ssize_t need, const char *name)
{
    int flags = PyBUF_FORMAT | PyBUF_C_CONTIGUOUS | (writable ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(obj, view, flags) < 0)
        return -1;
    if (view->itemsize != 8 || view->format == NULL || strcmp(view->format, "d") != 0) {
        PyErr_Format(PyExc_TypeError, "%s: a contiguous float64 array is needed", name);
        PyBuffer_Release(view);
        return -1;
    }
    if (view->len / 8 < need) {
        PyErr_Format(PyExc_ValueError, "%s: %zd values, at least %zd needed", name, view->len / 8, need);
        PyBuffer_Release(view);
        return -1;
    }
    return 0;
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
    if (B < 1 || nb < 0) {
        PyErr_SetString(PyExc_ValueError, "block_sums: block >= 1 and nb >= 0 are needed");
        return NULL;
    }
    Py_buffer x, s, w;
    if (doubles(xo, &x, 0, nb * B + 1, "x") < 0)
        return NULL;
    if (doubles(so, &s, 1, nb, "sums") < 0) {
        PyBuffer_Release(&x);
        return NULL;
    }
    int weighted = wo != Py_None;
    if (weighted && doubles(wo, &w, 1, nb, "weighted") < 0) {
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
    if (B < 1 || nb < 0) {
        PyErr_SetString(PyExc_ValueError, "encoder_steps: block >= 1 and nb >= 0 are needed");
        return NULL;
    }
    Py_buffer e, w;
    Py_ssize_t need = nb * B + 1 > 2 ? nb * B + 1 : 2;
    if (doubles(eo, &e, 0, need, "enc") < 0)
        return NULL;
    if (doubles(wo, &w, 1, nb, "weighted") < 0) {
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

static PyMethodDef methods[] = {
    {"block_sums", block_sums, METH_VARARGS, block_sums_doc},
    {"encoder_steps", encoder_steps, METH_VARARGS, encoder_steps_doc},
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
