"""A natural field campaign on which the discrimination design's convex program is unbounded
(found by studies/robustness.py: 2 positions, rates 20/40/60/-40, a -311 us sync delay hidden)
is still diagnosed: the ambiguous pair is named, with no proposal instead of a crash."""
import importlib.util
from pathlib import Path

import numpy as np

from hse_opt.diagnose import refine

_spec = importlib.util.spec_from_file_location(
    "robustness_study", Path(__file__).resolve().parents[1] / "studies" / "robustness.py")
study = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(study)


def test_a_failed_discrimination_design_does_not_stop_the_diagnosis():
    rng = np.random.default_rng([0, 1, study.hidden_effects().index("sync_delay"), 6])
    runs, truth = study.campaign("field", "sync_delay", rng)
    assert truth["delay"] < -300 and len(set(runs.position)) == 2
    steps = refine(runs)
    assert steps[0].verdict in ("missing-effect", "inconclusive")
    assert all(isinstance(d.proposals, tuple) for d in steps)


def test_refine_does_not_add_a_candidate_whose_refit_failed():
    """A natural stand campaign without a hidden effect (studies/robustness.py, 'none', seed
    20): encoder_harmonic's score test is significant but its refit cannot separate enc_c1,
    enc_s1 from offset and lambda2; refine stops at that diagnosis instead of raising."""
    names = ["none", *study.hidden_effects()]
    rng = np.random.default_rng([0, 0, (names.index("none") - 1) % 99, 20])
    runs, truth = study.campaign("stand", "none", rng)
    steps = refine(runs)
    failed = [c for c in steps[0].candidates if c.significant and c.fit is None]
    assert failed and failed[0].effect == "encoder_harmonic"
    assert all("encoder_harmonic" not in d.effects for d in steps)
