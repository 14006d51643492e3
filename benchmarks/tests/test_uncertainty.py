"""`benchmarks/benchmark_uncertainty.py`: how much of the wrong pixels the semantics uncertainty map holds."""

from __future__ import annotations

import numpy as np

from benchmarks.benchmark_uncertainty import detection


def test_uncertainty_detection_figures_tell_a_useful_map_from_chance() -> None:
    """The figures `benchmark_uncertainty` reports: 1 for a map bright exactly on the wrong pixels, 0 for the reverse,
    0.5 (AUROC) for a constant map, about the top share for a random one."""
    wrong = np.zeros(1000, dtype=bool)
    wrong[::10] = True
    useful = detection(wrong.astype(np.float64), wrong, 0.2)
    assert useful == {"auroc": 1.0, "wrong_in_top": 1.0}
    assert detection(1.0 - wrong, wrong, 0.2)["auroc"] == 0.0
    assert detection(np.full(1000, 0.3), wrong, 0.2)["auroc"] == 0.5
    chance = detection(np.random.default_rng(0).random(1000), wrong, 0.2)
    assert abs(chance["auroc"] - 0.5) < 0.1 and abs(chance["wrong_in_top"] - 0.2) < 0.1
