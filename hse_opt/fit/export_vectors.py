"""Test vectors for the exported compensation: inputs and the outputs expected on the target.

The navigation team compiles ``hse_compensation.c`` for its own computer; the test vectors
say whether it computes there what hse_opt computed here. :func:`write_test_vectors` writes,
beside the exported C (:func:`hse_opt.fit.export.export_calibration`):

``test_vectors.csv``
    One header row: the inputs by name with their SI unit (``in_rate_rad_s``, ...: the
    order of ``in[]``, ``calibration.json``'s ``inputs``), then ``correction_rad``,
    ``sigma_rad``, ``sigma_sys_rad`` (``hse_compensation_systematic``) and ``status``; one row per vector, every number with 17 significant digits
    (exact round trip of a double). The vectors are the calibration runs' own inputs (up to
    :data:`N_INSIDE`, spread over the runs: status 0) and, for each quantity of the validity
    domain (:mod:`hse_opt.fit.domain`), the first run moved far outside it (``|rate|``, time,
    duration or a covariate ten times the domain's width beyond it; C23 by the heading where it
    is farthest from the domain, when one leaves it), each input with a model limit at twice
    it, and the sense of rotation the runs never used where there is one. The expected outputs come from the measurement model the fit used
    (:func:`hse_opt.fit.correction.compensation_at`: minus the modelled heading error, and
    its 1-sigma from the covariance; :func:`hse_opt.fit.correction.systematic_at`, its
    systematic bound), not from the C; the expected status from
    :meth:`hse_opt.fit.domain.Domain.status`, the rule the C implements.
``test_hse_compensation.c``
    A C99 driver: reads the CSV, calls ``hse_compensation`` and ``hse_compensation_systematic``
    on each row and compares; prints
    one line per disagreement and a last line ``N of M test vectors agree``; exits 0 when all
    agree. Build and run::

        cc -std=c99 -O2 -o test_hse_compensation test_hse_compensation.c hse_compensation.c -lm
        ./test_hse_compensation test_vectors.csv

    Tolerance: |difference| <= ``ABS_TOL_RAD`` + ``REL_TOL`` |expected| for both outputs (the
    C evaluates the same expressions in another order: a few units in the last place), the
    status exactly. The C evaluates the cheapest of several equivalent forms of the model
    (:func:`hse_opt.fit.export.compensation_function`: linear parts folded, the tilts' sine and
    cosine as series), so it agrees with the model to rounding in those forms, about 1e-12 rad
    (2e-7 arcsec): far below any sigma.
"""
from __future__ import annotations

import os

import numpy as np

from .. import units
from ..data import write_text_atomic
from ..model.inputs import RUN_FIELDS

__all__ = ["N_INSIDE", "ABS_TOL_RAD", "REL_TOL", "VECTORS_NAME", "DRIVER_NAME", "vectors", "vectors_csv",
           "driver_source", "write_test_vectors"]

#: at most this many vectors inside the validity range (the calibration runs' own inputs)
N_INSIDE = 8
#: the driver's tolerance: absolute (rad; 1e-6 arcsec) ...
ABS_TOL_RAD = 1e-6 * units.ARCSEC
#: ... plus relative
REL_TOL = 1e-8
VECTORS_NAME = "test_vectors.csv"
DRIVER_NAME = "test_hse_compensation.c"
#: how far outside its domain interval a quantity is moved: this many times the interval's width
_OUTSIDE = 10.0


def vectors(fit_result, inputs=None):
    """The test vectors (module docstring).

    Parameters
    ----------
    fit_result : hse_opt.fit.FitResult
    inputs : numpy.ndarray, shape (n_x, n), optional
        The calibration runs' inputs (default ``fit_result.inputs``).

    Returns
    -------
    X : numpy.ndarray, shape (n_x, m)
        The vectors' inputs, SI.
    correction, sigma : numpy.ndarray, shape (m,)
        Expected ``*correction_rad`` and ``*sigma_rad``, rad.
    status : numpy.ndarray of int, shape (m,)
        Expected return value.
    """
    from .correction import compensation_at

    from .correction import validity_domain
    from ..model.inputs import RunInputs

    X0 = np.asarray(fit_result.inputs if inputs is None else inputs, dtype=float)
    domain = validity_domain(fit_result, X0)
    n = X0.shape[1]
    pick = np.unique(np.linspace(0, n - 1, min(n, N_INSIDE)).round().astype(int))
    cols = [X0[:, i] for i in pick]
    first = X0[:, 0]
    ix = RunInputs.INDEX
    for k, nm in enumerate(domain.bounded):
        x = first.copy()
        width = max(float(domain.upper[k] - domain.lower[k]), 1e-3 * max(abs(float(domain.upper[k])), 1.0))
        far = float(domain.upper[k]) + _OUTSIDE * width
        if nm == "rate":
            x[0] = np.copysign(far, first[0])                  # the domain is of |rate|
        elif nm == "c23":   # the heading where C23 = -roll cos + pitch sin is largest, if outside
            pitch, roll = x[ix["pitch"]], x[ix["roll"]]
            x[ix["azimuth"]] = np.mod(np.arctan2(pitch, -roll), 2 * np.pi)
            if np.hypot(pitch, roll) <= domain.upper[k]:
                x[ix["azimuth"]] += np.pi                       # the smallest, then
                if -np.hypot(pitch, roll) >= domain.lower[k]:
                    continue                                    # no heading leaves the domain
        else:
            x[domain.names.index(nm)] = far
        cols.append(x)
    for nm, limit in domain.limited().items():                  # beyond a model limit
        x = first.copy()
        x[ix[nm]] = 2.0 * limit
        cols.append(x)
    if len(domain.senses) == 1:
        x = first.copy()
        x[0] = -x[0]
        cols.append(x)
    X = np.array(cols).T
    heading_err, sigma = compensation_at(X, fit_result)
    return X, -heading_err, sigma, domain.status(X).astype(int)


def _unit_name(unit):
    return unit.replace("/", "_").replace(" ", "_")


def vectors_csv(fit_result, inputs=None):
    """The text of ``test_vectors.csv`` (module docstring)."""
    from .correction import systematic_at
    from .export import _input_table
    X, corr, sigma, status = vectors(fit_result, inputs)
    sys = systematic_at(X, fit_result)
    rows = _input_table(fit_result)
    head = [f"in_{r['name']}" + ("" if r["unit"].startswith("as in") else f"_{_unit_name(r['unit'])}")
            for r in rows] + ["correction_rad", "sigma_rad", "sigma_sys_rad", "status"]
    lines = [",".join(head)]
    for j in range(X.shape[1]):
        vals = [f"{v:.17g}" for v in X[:, j]] + [f"{corr[j]:.17g}", f"{sigma[j]:.17g}", f"{sys[j]:.17g}",
                                                 str(int(status[j]))]
        lines.append(",".join(vals))
    return "\n".join(lines) + "\n"


_DRIVER = r"""/* test_hse_compensation.c - runs hse_compensation on the test vectors hse_opt computed.
 *
 *   cc -std=c99 -O2 -o test_hse_compensation test_hse_compensation.c hse_compensation.c -lm
 *   ./test_hse_compensation test_vectors.csv
 *
 * test_vectors.csv: a header row, then per row the HSE_COMP_N_INPUTS inputs (SI, the order of
 * in[]), the expected correction_rad, sigma_rad, sigma_sys_rad (hse_compensation_systematic) and
 * return status. The outputs must agree to ABS_TOL_RAD + REL_TOL * |expected|, the statuses exactly. Prints each disagreement and
 * "N of M test vectors agree"; exit status 0 when all agree, 1 when one does not, 2 when the
 * file cannot be read.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include "hse_compensation.h"

#define ABS_TOL_RAD @ABS@
#define REL_TOL @REL@

static int close_enough(double got, double expected) {
  return fabs(got - expected) <= ABS_TOL_RAD + REL_TOL * fabs(expected);
}

int main(int argc, char **argv) {
  const char *path = argc > 1 ? argv[1] : "test_vectors.csv";
  FILE *f = fopen(path, "r");
  double in[HSE_COMP_N_INPUTS], expected[3], got[3];
  int c, k, row = 0, good = 0, status_expected;
  if (!f) {
    fprintf(stderr, "%s: cannot open\n", path);
    return 2;
  }
  while ((c = fgetc(f)) != '\n') { /* the header row */
    if (c == EOF) {
      fprintf(stderr, "%s: no header row\n", path);
      fclose(f);
      return 2;
    }
  }
  for (;;) {
    for (k = 0; k < HSE_COMP_N_INPUTS; k++)
      if (fscanf(f, " %lf ,", &in[k]) != 1) break;
    if (k == 0 && feof(f)) break;
    if (k < HSE_COMP_N_INPUTS ||
        fscanf(f, " %lf , %lf , %lf , %d", &expected[0], &expected[1], &expected[2], &status_expected) != 4) {
      fprintf(stderr, "%s: row %d: expected %d inputs, correction_rad, sigma_rad, sigma_sys_rad, status\n", path, row + 2,
              HSE_COMP_N_INPUTS);
      fclose(f);
      return 2;
    }
    int status = hse_compensation(in, &got[0], &got[1]);
    int status_sys = hse_compensation_systematic(in, &got[2]);
    row++;
    if (status == status_expected && status_sys == status_expected && close_enough(got[0], expected[0]) &&
        close_enough(got[1], expected[1]) && close_enough(got[2], expected[2])) {
      good++;
    } else {
      printf("vector %d: status %d (expected %d), correction_rad %.17g (expected %.17g), "
             "sigma_rad %.17g (expected %.17g), sigma_sys_rad %.17g (expected %.17g)\n", row, status,
             status_expected, got[0], expected[0], got[1], expected[1], got[2], expected[2]);
    }
  }
  fclose(f);
  printf("%d of %d test vectors agree\n", good, row);
  return good == row && row > 0 ? 0 : 1;
}
"""


def driver_source():
    """The text of ``test_hse_compensation.c`` (module docstring)."""
    return _DRIVER.replace("@ABS@", repr(ABS_TOL_RAD)).replace("@REL@", repr(REL_TOL))


def write_test_vectors(fit_result, directory, inputs=None):
    """Write ``test_vectors.csv`` and ``test_hse_compensation.c`` into ``directory`` (existing;
    each file whole or not at all).

    Returns
    -------
    tuple of str
        The file names written.
    """
    write_text_atomic(os.path.join(directory, VECTORS_NAME), vectors_csv(fit_result, inputs))
    write_text_atomic(os.path.join(directory, DRIVER_NAME), driver_source())
    return VECTORS_NAME, DRIVER_NAME
