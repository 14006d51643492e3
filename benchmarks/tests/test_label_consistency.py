"""`python -m benchmarks.label_consistency`: labels that agree between views score high, the same labels
moved to other frames score low, and data without depth ends in one line."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from benchmarks.label_consistency import LabelConsistencyConfig, label_consistency, main


def test_labels_moved_to_other_frames_agree_less(trained_scene, tmp_path: Path) -> None:
    scene, _ = trained_scene
    scores = label_consistency(LabelConsistencyConfig(scene, properties=("semantics", "keypoints")))
    assert set(scores) >= {"semantics_miou", "keypoints_f1", "keypoints_ap"} and "edges_f1" not in scores
    # generated labels of one scene seen from nearby views: far above chance
    assert scores["semantics_acc"] > 0.6 and scores["keypoints_f1"] > 0.3

    moved = tmp_path / "moved"
    shutil.copytree(scene, moved)
    meta = json.loads((moved / "transforms.json").read_text())
    files = [frame["keypoints_file_path"] for frame in meta["frames"]]
    for frame, other in zip(meta["frames"], files[len(files) // 2 :] + files[: len(files) // 2]):
        frame["keypoints_file_path"] = other  # each frame gets the keypoints of a view half the loop away
    (moved / "transforms.json").write_text(json.dumps(meta))
    output = tmp_path / "scores.json"
    shuffled = main(LabelConsistencyConfig(moved, properties=("semantics", "keypoints"), output=output))
    assert json.loads(output.read_text()) == shuffled
    assert shuffled["semantics_miou"] == scores["semantics_miou"]  # untouched labels score the same
    assert shuffled["keypoints_f1"] < scores["keypoints_f1"] - 0.1
    assert shuffled["keypoints_ap"] < scores["keypoints_ap"] - 0.1


def test_without_depth_maps_it_says_so_and_writes_nothing(trained_scene, tmp_path: Path) -> None:
    scene, _ = trained_scene
    bare = tmp_path / "bare"
    shutil.copytree(scene, bare)
    meta = json.loads((bare / "transforms.json").read_text())
    for frame in meta["frames"]:
        frame.pop("depth_file_path", None)
    (bare / "transforms.json").write_text(json.dumps(meta))
    output = tmp_path / "scores.json"
    with pytest.raises(ValueError, match=r"transforms.json: no depth maps.*depth_file_path") as error:
        main(LabelConsistencyConfig(bare, output=output))
    assert "\n" not in str(error.value) and not output.exists()
