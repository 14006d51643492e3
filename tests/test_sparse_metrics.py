"""Edge and keypoint F1 / AP against hand-built maps: an empty map scores 0, the label itself 1, a one-pixel shift
of an edge map still 1 and a three-pixel shift not; the split's F1 uses one threshold for all views."""

from __future__ import annotations

import pytest
import torch

from ssnerf_method.metrics import METRICS, SPARSE_THRESHOLDS, add_statistics, local_maxima

HEIGHT, WIDTH = 40, 50
EVERYWHERE = torch.ones(HEIGHT, WIDTH, dtype=torch.bool)


def edge_label() -> torch.Tensor:
    """A vertical and a horizontal 1-pixel line, away from the border."""
    label = torch.zeros(HEIGHT, WIDTH, 1)
    label[5:35, 20] = 1.0
    label[28, 30:45] = 1.0
    return label


def keypoint_label(centres, peak: float = 1.0) -> torch.Tensor:
    """Gaussian blobs (sigma 1.5 px) of height `peak` at (row, column) `centres`, combined by max."""
    rows, columns = torch.meshgrid(torch.arange(HEIGHT), torch.arange(WIDTH), indexing="ij")
    label = torch.zeros(HEIGHT, WIDTH)
    for row, column in centres:
        blob = peak * torch.exp(-((rows - row) ** 2 + (columns - column) ** 2) / (2 * 1.5**2))
        label = torch.maximum(label, blob)
    return label[..., None]


CENTRES = [(10, 10), (20, 30), (30, 40), (8, 42)]


def test_edge_f1_empty_label_and_shifts() -> None:
    metric, label = METRICS["edge"], edge_label()
    assert metric(torch.zeros_like(label), label, EVERYWHERE, 0)["f1"] == 0.0
    assert metric(torch.zeros_like(label), label, EVERYWHERE, 0)["ap"] == 0.0
    itself = metric(label, label, EVERYWHERE, 0)
    assert itself["f1"] == pytest.approx(1.0) and itself["ap"] == pytest.approx(1.0)
    one_right = torch.roll(label, 1, dims=1)
    assert metric(one_right, label, EVERYWHERE, 0)["f1"] == pytest.approx(1.0)
    three = torch.roll(torch.roll(label, 3, dims=1), 3, dims=0)
    assert metric(three, label, EVERYWHERE, 0)["f1"] < 0.2


def test_edge_f1_hand_computed_precision_and_recall() -> None:
    """Half the true edge found, plus as many false pixels far away: precision 1/2, recall 1/2, F1 1/2."""
    label = torch.zeros(HEIGHT, WIDTH, 1)
    label[5:25, 10] = 1.0  # 20 true pixels
    prediction = torch.zeros_like(label)
    prediction[5:15, 10] = 0.8  # 10 of them found
    prediction[5:15, 40] = 0.8  # 10 false pixels
    values = METRICS["edge"](prediction, label, EVERYWHERE, 0)
    # rows 15 and 4 of the true line lie within a pixel of a found one: recall 11/20 (8-neighbourhood tolerance)
    precision, recall = 0.5, 11 / 20
    assert values["f1"] == pytest.approx(2 * precision * recall / (precision + recall))
    assert values["f1_threshold"] == pytest.approx(0.01)  # every threshold up to 0.8 ties; the lowest is reported


def test_edge_soft_render_scores_at_its_best_threshold_where_l1_does_not() -> None:
    """A faint but exact edge map has a worse L1 than an empty one, and F1 1 at a low threshold."""
    label = edge_label()
    faint = label * 0.3
    metric = METRICS["edge"]
    assert metric(faint, label, EVERYWHERE, 0)["l1"] > 0.0
    assert metric(faint, label, EVERYWHERE, 0)["f1"] == pytest.approx(1.0)
    assert metric(faint, label, EVERYWHERE, 0)["f1_threshold"] <= 0.3


def test_edge_split_f1_uses_one_threshold_for_all_views() -> None:
    """View A is right only above 0.6, view B only below 0.4: each alone scores 1, the split cannot."""
    label = edge_label()
    noise = torch.zeros_like(label)
    noise[:, 0:3] = 0.5  # a false band at 0.5 in both views
    view_a = torch.maximum(label * 0.9, noise)
    view_b = torch.maximum(label * 0.3, noise * 0.5)  # false band at 0.25 < its edges at 0.3
    metric = METRICS["edge"]
    assert metric(view_a, label, EVERYWHERE, 0)["f1"] == pytest.approx(1.0)
    assert metric(view_b, label, EVERYWHERE, 0)["f1"] == pytest.approx(1.0)
    split = add_statistics(metric.statistics(view_a, label, EVERYWHERE, 0),
                           metric.statistics(view_b, label, EVERYWHERE, 0))
    assert metric.summarize(split)["f1"] < 0.99


def test_edge_metric_ignores_unlabelled_pixels() -> None:
    label, prediction = edge_label(), edge_label()
    prediction[:, 45:] = 1.0  # false edges only where nothing is labelled
    labelled = EVERYWHERE.clone()
    labelled[:, 44:] = False
    assert METRICS["edge"](prediction, label, labelled, 0)["f1"] == pytest.approx(1.0)
    assert METRICS["edge"](prediction, label, EVERYWHERE, 0)["f1"] < 1.0


def test_keypoint_f1_empty_label_and_shifts() -> None:
    metric, label = METRICS["keypoint"], keypoint_label(CENTRES)
    empty = metric(torch.zeros_like(label), label, EVERYWHERE, 0)
    assert empty["f1"] == 0.0 and empty["ap"] == 0.0
    itself = metric(label, label, EVERYWHERE, 0)
    assert itself["f1"] == pytest.approx(1.0) and itself["ap"] == pytest.approx(1.0)
    assert metric(torch.roll(label, 3, dims=1), label, EVERYWHERE, 0)["f1"] == pytest.approx(1.0)  # within 3 px
    assert metric(torch.roll(label, 4, dims=1), label, EVERYWHERE, 0)["f1"] == 0.0


def test_keypoint_f1_hand_computed_with_a_weak_true_peak_and_a_false_one() -> None:
    """The label's peaks above 0.5 are its keypoints (a 0.4 blob is not one); one prediction is a false peak."""
    label = torch.maximum(keypoint_label(CENTRES), keypoint_label([(30, 10)], peak=0.4))
    truth, _ = local_maxima(label[..., 0], EVERYWHERE, 0.5)
    assert sorted(map(tuple, truth.tolist())) == sorted(CENTRES)
    prediction = keypoint_label([*CENTRES[:3], (35, 25)], peak=0.7)  # 3 of 4 found, 1 false
    values = METRICS["keypoint"](prediction, label, EVERYWHERE, 0)
    assert values["f1"] == pytest.approx(2 * 0.75 * 0.75 / 1.5)


def test_keypoint_one_prediction_matches_one_keypoint() -> None:
    """Two true keypoints 2 px apart and one predicted peak between them: one hit, one miss."""
    label = torch.zeros(HEIGHT, WIDTH, 1)
    label[20, 20, 0] = label[20, 23, 0] = 1.0
    prediction = torch.zeros_like(label)
    prediction[20, 21, 0] = 0.9
    values = METRICS["keypoint"](prediction, label, EVERYWHERE, 0)
    assert values["f1"] == pytest.approx(2 * 1.0 * 0.5 / 1.5)


def test_flat_topped_peak_counts_once() -> None:
    values = torch.zeros(HEIGHT, WIDTH)
    values[10:13, 10:13] = 0.8
    positions, _ = local_maxima(values, EVERYWHERE, 0.5)
    assert len(positions) == 1


def test_thresholds_cover_the_unit_interval() -> None:
    assert SPARSE_THRESHOLDS[0] == pytest.approx(0.01) and SPARSE_THRESHOLDS[-1] == pytest.approx(1.0)
