"""`ssnerf-demo` end to end on a tiny scene: trains, reloads the checkpoint, scores, writes metrics and renders."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from ssnerf_method.cli.demo import DemoConfig, run
from ssnerf_method.metrics import METRICS
from ssnerf_method.properties import REGISTRY

REPORTED = {spec.metric_prefix + key for spec in REGISTRY.values() for key, _ in METRICS[spec.metric].reported}
"""Every property's reported numbers (the paper's headline and the measures beside it)."""
MODEL_ONLY = {"depth_l1", "depth_rmse", *(f"{spec.metric_prefix}{METRICS[spec.metric].reported[0][0]}_per_view"
                                          for spec in REGISTRY.values() if spec.kind.categorical)}
"""The model's column only: depth (the copied labels have none), and class metrics' mean over views."""
PROPERTIES = tuple(REGISTRY)


@pytest.fixture(autouse=True)
def single_thread():
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)


def test_demo_writes_metrics_and_renders(tmp_path: Path) -> None:
    out = tmp_path / "demo"
    run(DemoConfig(output_dir=out, method="ssnerf-lite", max_num_iterations=10, width=48, height=36, num_frames=10))
    summary = json.loads((out / "metrics.json").read_text())
    columns = summary["results"]
    assert set(columns) == {"ssnerf-lite (step 9)", "nearest training view"}
    model, copy = set(columns["ssnerf-lite (step 9)"]), set(columns["nearest training view"])
    assert REPORTED <= copy and model == copy | MODEL_ONLY
    for scores in columns.values():
        assert all(value == value for value in scores.values())  # no NaN
    views = sorted((out / "renders").iterdir())
    assert len(views) == 2  # frames 2 and 7 of 10 are the test views
    for view in views:
        assert {path.stem for path in view.glob("*.png")} == set(PROPERTIES)
    grid = np.asarray(Image.open(out / "summary.png").convert("RGB")).astype(int)
    first = np.asarray(Image.open(views[0] / "semantics.png").convert("RGB")).astype(int)
    assert grid.shape[1] > grid.shape[0]  # one column per property, two rows (ground truth, SS-NeRF)
    # the summary shows view 0's semantics ground truth: its class colours appear in the grid
    truth_colours = {tuple(colour) for colour in first[:, : first.shape[1] // 2].reshape(-1, 3)}
    grid_colours = {tuple(colour) for colour in grid.reshape(-1, 3)}
    assert len(truth_colours & grid_colours) >= min(3, len(truth_colours))
    with pytest.raises(SystemExit, match="--overwrite"):
        run(DemoConfig(output_dir=out, method="ssnerf-lite", max_num_iterations=10, width=48, height=36, num_frames=10))
