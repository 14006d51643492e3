"""Every metric against hand-computed values and edge cases, per view and accumulated over a split, and `ns-eval`'s
split-level output on a trained model."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from ssnerf_method.metrics import METRICS, add_statistics, histogram_median
from ssnerf_method.properties import SEMANTIC_IGNORE, ClassKind, NormalKind, ScalarKind

ALL = torch.ones(2, 2, dtype=torch.bool)


def encode(normals) -> torch.Tensor:
    """(n+1)/2 encoding of a list of normals, as a (1, N, 3) image."""
    return (torch.tensor(normals, dtype=torch.float64)[None] + 1.0) / 2.0


def test_psnr_and_ssim() -> None:
    image = torch.rand(8, 8, 3, generator=torch.Generator().manual_seed(0))
    same = METRICS["psnr"](image, image, torch.ones(8, 8, dtype=torch.bool), 0)
    assert same["psnr"] > 60 and same["ssim"] > 0.99
    off = METRICS["psnr"](torch.full((8, 8, 3), 0.5), torch.full((8, 8, 3), 0.6), torch.ones(8, 8, dtype=torch.bool), 0)
    assert off["psnr"] == pytest.approx(20.0, abs=1e-3)  # mse 0.01
    # Over a split, PSNR is the mean of the views' PSNRs (20 dB and 40 dB -> 30 dB), not the PSNR of the mean MSE.
    far = METRICS["psnr"].statistics(torch.full((8, 8, 3), 0.5), torch.full((8, 8, 3), 0.6), ALL, 0)
    near = METRICS["psnr"].statistics(torch.full((8, 8, 3), 0.5), torch.full((8, 8, 3), 0.51), ALL, 0)
    assert METRICS["psnr"].summarize(add_statistics(far, near))["psnr"] == pytest.approx(30.0, abs=1e-3)


def test_l1_hand_computed_and_accumulated_over_pixels() -> None:
    prediction = torch.tensor([[[0.2], [0.5]], [[1.0], [0.0]]])
    label = torch.tensor([[[0.4], [0.5]], [[float("nan")], [0.3]]])
    valid = ScalarKind("sigmoid").valid(label)
    assert METRICS["l1"](prediction, label, valid, 0)["l1"] == pytest.approx((0.2 + 0.0 + 0.3) / 3)
    unlabelled = torch.full_like(label, float("nan"))
    nothing = METRICS["l1"].statistics(prediction, unlabelled, torch.zeros(2, 2, dtype=torch.bool), 0)
    assert math.isnan(METRICS["l1"].summarize(nothing)["l1"])
    # A view without labels does not make the split NaN; the split averages over its 3 + 4 labelled pixels.
    first = METRICS["l1"].statistics(prediction, label, valid, 0)
    second = METRICS["l1"].statistics(torch.zeros(2, 2, 1), torch.full((2, 2, 1), 0.1), ALL, 0)
    split = add_statistics(add_statistics(first, nothing), second)
    assert METRICS["l1"].summarize(split)["l1"] == pytest.approx((0.5 + 0.4) / 7)


def test_miou_hand_computed_with_absent_class_and_unlabelled() -> None:
    num_classes = 4
    labels = torch.tensor([[0, 0, 1], [1, 2, SEMANTIC_IGNORE]], dtype=torch.float32)[..., None]
    predicted = torch.tensor([[0, 1, 1], [1, 3, 0]])
    logits = F.one_hot(predicted, num_classes).float() * 3.0
    valid = ClassKind().valid(labels)
    result = METRICS["miou"](logits, labels, valid, num_classes)
    # class 0: TP 1, union 2; class 1: TP 2, union 3; class 2: TP 0, union 1; class 3 is predicted but absent from
    # the labels: left out. The unlabelled pixel (predicted 0) counts nowhere.
    assert result["miou"] == pytest.approx((1 / 2 + 2 / 3 + 0) / 3)
    assert result["acc"] == pytest.approx(3 / 5)
    nothing = METRICS["miou"](logits, torch.full_like(labels, SEMANTIC_IGNORE), torch.zeros(2, 3, dtype=torch.bool), 4)
    assert math.isnan(nothing["miou"]) and math.isnan(nothing["acc"])


def test_miou_accumulated_over_the_split_differs_from_per_view_mean() -> None:
    """View A: class 0 everywhere, all right. View B: class 1, one pixel of four wrong (predicted 0)."""
    num_classes = 2
    a_labels, a_logits = torch.zeros(2, 2, 1), F.one_hot(torch.zeros(2, 2).long(), 2).float()
    b_labels = torch.ones(2, 2, 1)
    b_logits = F.one_hot(torch.tensor([[1, 1], [1, 0]]), 2).float()
    view_a = METRICS["miou"].statistics(a_logits, a_labels, ALL, num_classes)
    view_b = METRICS["miou"].statistics(b_logits, b_labels, ALL, num_classes)
    per_view = (METRICS["miou"].summarize(view_a)["miou"] + METRICS["miou"].summarize(view_b)["miou"]) / 2
    assert per_view == pytest.approx((1.0 + 0.75) / 2)  # in B, class 0 is absent from the labels: left out
    split = METRICS["miou"].summarize(add_statistics(view_a, view_b))
    # Accumulated: class 0 TP 4, union 5; class 1 TP 3, union 4.
    assert split["miou"] == pytest.approx((4 / 5 + 3 / 4) / 2)
    assert split["acc"] == pytest.approx(7 / 8)


def test_normal_angles_hand_computed() -> None:
    s, c = math.sqrt(0.5), math.sqrt(0.75)
    truth = encode([[0, 0, 1], [0, 0, 1], [0, 0, 1], [1, 0, 0], [0, 0, 1]])
    prediction = encode([[0, 0, 1], [s, 0, s], [0, 1, 0], [0, 1, 0], [c, 0, 0.5]])  # 0, 45, 90, 90, 60 deg off
    valid = NormalKind().valid(truth)
    result = METRICS["normal"](prediction, truth, valid, 0)
    assert result["angle_mean_deg"] == pytest.approx((0 + 45 + 90 + 90 + 60) / 5, abs=1e-6)
    assert result["angle_median_deg"] == pytest.approx(60.0, abs=0.1)
    assert result["within_11_25_deg"] == pytest.approx(1 / 5)
    assert result["within_22_5_deg"] == pytest.approx(1 / 5)
    assert result["within_30_deg"] == pytest.approx(1 / 5)
    per_pixel = [0, s / 2 + (1 - s) / 2, 0.5 + 0.5, 0.5 + 0.5, c / 2 + 0.25]
    assert result["l1"] == pytest.approx(sum(per_pixel) / 15)


def test_normal_metric_edge_cases() -> None:
    truth = encode([[0, 0, 1], [0, 0, 1], [float("nan")] * 3])
    prediction = encode([[0, 0, 0], [0, 0, 1], [0, 0, 1]])  # a zero normal (no direction), a perfect one
    valid = NormalKind().valid(truth)
    assert valid.tolist() == [[True, True, False]]
    result = METRICS["normal"](prediction, truth, valid, 0)
    assert result["angle_mean_deg"] == pytest.approx(0.0, abs=1e-6)  # the zero normal has no angle
    assert result["within_11_25_deg"] == 1.0
    assert result["l1"] == pytest.approx((0.5 / 3 + 0.0) / 2)  # but it is an L1 error on the encoding
    nothing = METRICS["normal"](prediction, truth, torch.zeros(1, 3, dtype=torch.bool), 0)
    assert all(math.isnan(value) for value in nothing.values())


def test_histogram_median_interpolates_within_a_bin() -> None:
    values = torch.tensor([1.0, 2.0, 3.0, 10.0, 50.0], dtype=torch.float64)
    histogram = torch.histc(values, bins=1800, min=0.0, max=180.0).double()
    assert histogram_median(histogram) == pytest.approx(3.0, abs=0.1)


def test_depth_l1_and_rmse() -> None:
    prediction = torch.tensor([[[1.0], [2.5]], [[4.0], [0.0]]])
    truth = torch.tensor([[[1.5], [2.0]], [[2.0], [0.0]]])  # 0 = no depth there
    result = METRICS["depth"](prediction, truth, (truth > 0)[..., 0], 0)
    assert result["l1"] == pytest.approx((0.5 + 0.5 + 2.0) / 3)
    assert result["rmse"] == pytest.approx(math.sqrt((0.25 + 0.25 + 4.0) / 3))


@pytest.mark.filterwarnings("ignore")
def test_ns_eval_writes_split_level_metrics(tmp_path: Path) -> None:
    """A short run on the tiny dataset (which has depth maps); `ns-eval` on its checkpoint writes every metric name
    other tools read, the split-level mIoU and the per-view one."""
    from test_training import lite_config, train, write_learnable_dataset

    data = write_learnable_dataset(tmp_path / "data")
    config = lite_config(data, tmp_path / "outputs", iterations=3)
    config.steps_per_save = 2
    train(config)
    output = tmp_path / "eval.json"
    result = subprocess.run(
        [sys.executable, "-m", "nerfstudio.scripts.eval", "--load-config", str(config.get_base_dir() / "config.yml"),
         "--output-path", str(output)],
        capture_output=True, text=True, timeout=300,
    )
    assert result.returncode == 0, result.stderr[-2000:]
    metrics = json.loads(output.read_text())["results"]
    expected = {"psnr", "ssim", "semantics_miou", "semantics_acc", "semantics_miou_per_view", "normals_l1",
                "normals_angle_mean_deg", "normals_angle_median_deg", "normals_within_11_25_deg",
                "normals_within_22_5_deg", "normals_within_30_deg", "shading_l1", "keypoints_l1", "edges_l1",
                "depth_l1", "depth_rmse"}
    assert expected <= set(metrics)
    assert all(np.isfinite(metrics[name]) for name in expected)
    assert 0 <= metrics["normals_angle_median_deg"] <= 180 and metrics["depth_rmse"] >= metrics["depth_l1"]
