"""`ssnerf-benchmark`: its tables from hand-made results, and `--quick` end to end (two tiny generated scenes), then
resumed without retraining anything."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from nerfstudio.engine.schedulers import MultiStepSchedulerConfig

from ssnerf_method.evaluation.hybrid import HybridBaseline
from ssnerf_method.experiments import benchmark
from ssnerf_method.experiments.benchmark import BenchmarkConfig, run
from ssnerf_method.experiments.report import beats, table1, table2
from ssnerf_method.properties import OPTIONAL_PROPERTIES

PROPERTIES = OPTIONAL_PROPERTIES


def test_tables_average_scenes_and_judge_each_metric_the_right_way() -> None:
    results = {
        "a": {"nerf": {"psnr": 20.0}, "ssnerf-semantics": {"psnr": 21.0, "semantics_miou": 0.8},
              "ssnerf-normals": {"psnr": 19.0, "normals_l1": 0.02},
              "heuristic": {"semantics_miou": 0.7, "normals_l1": 0.03}},
        "b": {"nerf": {"psnr": 22.0}, "ssnerf-semantics": {"psnr": 23.0, "semantics_miou": 0.6},
              "ssnerf-normals": {"psnr": 25.0, "normals_l1": 0.04},
              "heuristic": {"semantics_miou": 0.75, "normals_l1": 0.02}},
    }
    rows = table1(results, ("semantics", "normals"))
    assert [row["row"] for row in rows] == ["SS-NeRF (a)", "SS-NeRF (b)", "SS-NeRF, average", "Heuristic, average"]
    assert rows[2]["semantics"] == pytest.approx(0.7) and rows[2]["normals"] == pytest.approx(0.03)
    assert rows[3]["semantics"] == pytest.approx(0.725) and rows[3]["normals"] == pytest.approx(0.025)
    # mIoU: higher is better (0.7 < 0.725: loses); L1: lower is better (0.03 > 0.025: loses)
    assert beats(rows, ("semantics", "normals"), "Heuristic") == {"semantics": ["miou"], "normals": ["l1"]}
    assert beats([{**rows[2], "normals": 0.02}, rows[3]], ("normals",), "Heuristic") == {"normals": []}
    psnr = table2(results, ("semantics", "normals"))
    assert psnr[-1] == {"row": "average", "nerf": 21.0, "ssnerf-semantics": 22.0, "ssnerf-normals": 22.0}


def test_sparse_maps_are_judged_by_f1_and_ap_not_l1() -> None:
    """An empty edge map's L1 ties a good map's, so F1 and AP decide the sparse maps: a worse L1 with better F1 and
    AP is a win, and a worse F1 alone is a loss named by its measure."""
    ours = {"row": "SS-NeRF, average", "keypoints": 0.06, "keypoints_f1": 0.60, "keypoints_ap": 0.50}
    theirs = {"row": "Heuristic, average", "keypoints": 0.05, "keypoints_f1": 0.59, "keypoints_ap": 0.49}
    assert beats([ours, theirs], ("keypoints",), "Heuristic") == {"keypoints": []}
    assert beats([{**ours, "keypoints_f1": 0.58}, theirs], ("keypoints",), "Heuristic") == {"keypoints": ["f1"]}
    assert beats([{**ours, "keypoints_f1": 0.58, "keypoints_ap": 0.4}, theirs], ("keypoints",), "Heuristic") == {
        "keypoints": ["f1", "ap"]}


@pytest.mark.filterwarnings("ignore")
def test_quick_benchmark_end_to_end_then_resumes(tmp_path: Path, monkeypatch) -> None:
    torch.set_num_threads(1)
    output = tmp_path / "report"
    results = run(BenchmarkConfig(quick=True, output=output))
    assert set(results) == {"walkthrough_seed_0", "walkthrough_seed_1"}
    expected_rows = {"nerf", *(f"ssnerf-{name}" for name in PROPERTIES), "ssnerf-all", "heuristic", "hybrid",
                     "nearest"}
    for rows in results.values():
        assert set(rows) == expected_rows
        assert set(rows["nerf"]) >= {"psnr", "ssim"} and "semantics_miou" not in rows["nerf"]
        assert {"psnr", "semantics_miou", "semantics_acc"} <= set(rows["ssnerf-semantics"])
        assert "normals_l1" not in rows["ssnerf-semantics"]  # one property per model
        assert {"semantics_miou", "normals_l1", "edges_l1"} <= set(rows["heuristic"]) and "psnr" not in rows["hybrid"]
        # the copied nearest view is a floor, not the warp: it scores every property and differs from the Heuristic
        assert {"semantics_miou", "keypoints_f1", "edges_f1"} <= set(rows["nearest"])
        assert rows["nearest"]["normals_l1"] != rows["heuristic"]["normals_l1"]

    report = (output / "report.md").read_text()
    assert "## Table 1" in report and "| Heuristic, average |" in report and "| Hybrid, average |" in report
    assert "| Nearest training view copied, average |" in report
    assert "SS-NeRF-SL" in report
    tables = json.loads((output / "tables.json").read_text())
    assert [row["row"] for row in tables["table1"]][-5:] == [
        "SS-NeRF, average", "SS-NeRF, one model for all properties, average", "Heuristic, average", "Hybrid, average",
        "Nearest training view copied, average"]
    assert all(np.isfinite(value) for row in tables["table1"] for key, value in row.items() if key != "row")
    for scene in results:
        figure = np.asarray(Image.open(output / f"figure_{scene}.png"))
        assert figure.shape[0] > 400 and figure.shape[1] > 800 and figure.std() > 10  # a real picture, not blank

    def refuse(*args, **kwargs):
        raise AssertionError("a finished step was redone")

    monkeypatch.setattr(benchmark, "train_in_process", refuse)
    monkeypatch.setattr(HybridBaseline, "fit", refuse)
    assert run(BenchmarkConfig(quick=True, output=output)) == results
    # another step count is another training: the 30-step results are not passed off as its own
    with pytest.raises(AssertionError, match="redone"):
        run(BenchmarkConfig(quick=True, output=output, steps=31))


def test_rendered_depth_is_z_depth() -> None:
    """The Heuristic's fallback depth divides the rendered ray distance by the camera-frame ray length."""

    class Model:
        def render_camera(self, cameras):
            norm = torch.tensor([1.0, 2.0 ** 0.5, 3.0 ** 0.5]).reshape(1, 3, 1)
            return {"depth": 2.0 * norm, "directions_norm": norm}

    class Pipeline:
        model = Model()

    depth = benchmark.rendered_depth(Pipeline(), [None, None])(1)  # type: ignore[arg-type]
    assert depth.shape == (1, 3) and np.allclose(depth, 2.0)


def test_lr_drop_replaces_every_schedule_and_names_the_runs_apart(tmp_path: Path) -> None:
    scene = tmp_path / "scene"
    plain = benchmark.SceneBenchmark(BenchmarkConfig(output=tmp_path, steps=200), scene, "a")
    dropped = benchmark.SceneBenchmark(BenchmarkConfig(output=tmp_path, steps=200, lr_drop=0.75), scene, "a")
    trainer = dropped.trainer_config(benchmark.ModelRun("nerf", ()))
    assert set(trainer.optimizers) == set(plain.trainer_config(benchmark.ModelRun("nerf", ())).optimizers)
    for optimizer in trainer.optimizers.values():
        scheduler = optimizer["scheduler"]
        assert isinstance(scheduler, MultiStepSchedulerConfig)
        assert scheduler.milestones == (150,) and scheduler.gamma == 0.1 and scheduler.max_steps == 200
    assert plain.config_path("nerf") != dropped.config_path("nerf")
    assert dropped.config_path("nerf").parent.name == "200-steps-lr-drop-0.75"
    with pytest.raises(ValueError, match="strictly between 0 and 1"):
        benchmark.SceneBenchmark(BenchmarkConfig(output=tmp_path, steps=200, lr_drop=1.5), scene, "a")
