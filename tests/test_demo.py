"""`ssnerf-demo` end to end on a tiny scene: trains, reloads the checkpoint, scores, writes metrics and renders."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from ssnerf_method.scripts.demo import DemoConfig, run

METRICS = {"psnr", "ssim", "semantics_miou", "semantics_acc", "normals_l1", "normals_angle_mean_deg",
           "normals_angle_median_deg", "normals_within_11_25_deg", "normals_within_22_5_deg", "normals_within_30_deg",
           "shading_l1", "keypoints_l1", "edges_l1", *(f"{name}_{measure}" for name in ("keypoints", "edges")
                                                          for measure in ("f1", "f1_threshold", "ap"))}
MODEL_ONLY = {"semantics_miou_per_view", "depth_l1", "depth_rmse"}  # the copied labels have no depth
PROPERTIES = ("rgb", "semantics", "normals", "shading", "keypoints", "edges")


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
    assert set(columns["ssnerf-lite (step 9)"]) == METRICS | MODEL_ONLY
    assert set(columns["nearest training view"]) == METRICS
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
