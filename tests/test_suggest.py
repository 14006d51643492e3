"""Labelling where the model asks: `ssnerf-label --suggest-frames K` and `--suggest-clicks N`, and answered clicks
imported with `--annotations` (added over what the data has, each import in the provenance).

Frames: the greedy cover picks the frame adding most each time, and K suggested frames see more of the scene than K
evenly spaced ones. Clicks: from the shared trained fixture on a copy of its scene without semantics, the questions
are training pixels, spread in 3D; answered from the true labels, they label exactly those pixels, and a second
answered file adds to the first. Bad answer files end in one line naming the file, with nothing written.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Dict, List

import numpy as np
import pytest
from PIL import Image

from ssnerf_method.cli.label import main as label_main
from ssnerf_method.data.transforms import load_transforms
from ssnerf_method.label_makers.encoding import SEMANTIC_IGNORE
from ssnerf_method.label_tool.label_dataset import LabelDatasetConfig
from ssnerf_method.label_tool.suggest import (
    SUGGESTED_CLICKS,
    SUGGESTED_FRAMES,
    frame_views,
    greedy_cover,
    surface_voxels,
    training_frames,
)
from ssnerf_method.properties import class_property
from ssnerf_method.scene.make_scene import MakeSceneConfig, make_scene

from conftest import ssnerf_label_refuses

KEY = class_property().file_key
NO_LABELS = dict(edges=False, keypoints=False, normals=False, shading=False, workers=1)
"""Only semantics (the properties' other makers are not what these tests are about)."""


def test_greedy_cover_takes_the_largest_gain_each_time() -> None:
    seen = np.array([[1, 1, 0, 0, 0], [0, 0, 1, 1, 0], [1, 1, 1, 0, 0], [0, 0, 0, 0, 1]], dtype=bool)
    assert greedy_cover(seen, 3) == [(2, 3), (1, 1), (3, 1)]  # frame 0 then adds nothing
    assert greedy_cover(seen, 2, covered=np.array([0, 0, 1, 1, 1], dtype=bool)) == [(0, 2), (1, 0)]


@pytest.fixture(scope="module")
def walk(tmp_path_factory) -> Path:
    """A generated 48x36 walk through the room: 24 frames with depth (every fifth held out)."""
    scene = tmp_path_factory.mktemp("walk") / "scene"
    make_scene(MakeSceneConfig(output_dir=scene, width=48, height=36, num_frames=24, path_frames=0))
    return scene


def test_suggested_frames_see_more_of_the_scene_than_evenly_spaced_ones(walk: Path, tmp_path: Path) -> None:
    data = without_semantics(walk, tmp_path / "data")
    label_main(LabelDatasetConfig(data=data, suggest_frames=4, **NO_LABELS))
    record = json.loads((data / "ssnerf_labels" / SUGGESTED_FRAMES).read_text())
    transforms = load_transforms(data)
    train = [frame["file_path"] for frame in training_frames(transforms)]
    held_out = {frame["file_path"] for frame in transforms.frames} - set(train)
    assert held_out and held_out == {*transforms.meta["test_filenames"], *transforms.meta["val_filenames"]}
    assert len(record["frames"]) == len(set(record["frames"])) == 4 and set(record["frames"]) <= set(train)
    shares = record["added_share"]
    assert all(share > 0 for share in shares) and shares == sorted(shares, reverse=True)

    views = frame_views(transforms, training_frames(transforms), None)
    voxels = surface_voxels(views)
    index = {view.file_path: i for i, view in enumerate(views)}

    def coverage(paths: List[str]) -> float:
        return float(voxels.seen[[index[path] for path in paths]].any(axis=0).mean())

    assert coverage(record["frames"]) == pytest.approx(sum(shares), abs=1e-3)
    assert max(voxels.seen.mean(axis=1)) == pytest.approx(shares[0], abs=1e-3)  # the best single frame first
    even = [train[int(i)] for i in np.linspace(0, len(train) - 1, 4).round()]
    assert coverage(record["frames"]) > coverage(even) + 0.02, (coverage(record["frames"]), coverage(even))

    # frames that already list semantics count first and are never suggested
    meta = json.loads((walk / "transforms.json").read_text())
    labelled = {frame["file_path"]: frame[KEY] for frame in meta["frames"]}
    meta = json.loads((data / "transforms.json").read_text())
    for frame in meta["frames"]:
        if frame["file_path"] in record["frames"][:2]:
            frame[KEY] = str(walk / labelled[frame["file_path"]])
    (data / "transforms.json").write_text(json.dumps(meta))
    label_main(LabelDatasetConfig(data=data, suggest_frames=2, **NO_LABELS))
    again = json.loads((data / "ssnerf_labels" / SUGGESTED_FRAMES).read_text())
    assert again["already_annotated"] == sorted(record["frames"][:2], key=train.index)
    assert again["already_annotated_share"] == pytest.approx(sum(shares[:2]), abs=1e-3)
    assert again["frames"] == record["frames"][2:4]


def without_semantics(scene: Path, destination: Path) -> Path:
    """A copy of `scene` whose frames list no semantics (the class list stays)."""
    data = shutil.copytree(scene, destination)
    meta = json.loads((data / "transforms.json").read_text())
    for frame in meta["frames"]:
        frame.pop(KEY, None)
    (data / "transforms.json").write_text(json.dumps(meta, indent=2))
    return data


def answered(data: Path, truth: Path, clicks: List[Dict]) -> List[Dict]:
    """`clicks` answered from the true labels of `truth` (the scene the copy came from)."""
    meta = {frame["file_path"]: frame for frame in json.loads((truth / "transforms.json").read_text())["frames"]}
    classes = json.loads((truth / "transforms.json").read_text())["semantic_classes"]
    out = []
    for click in clicks:
        label = np.asarray(Image.open(truth / meta[click["file_path"]][KEY]))
        out.append({**click, "class": classes[int(label[click["y"], click["x"]])]})
    return out


def semantics_of(data: Path) -> Dict[str, np.ndarray]:
    frames = json.loads((data / "transforms.json").read_text())["frames"]
    return {frame["file_path"]: np.asarray(Image.open(data / frame[KEY])) for frame in frames if KEY in frame}


def test_suggested_clicks_answered_label_exactly_those_pixels_and_add_up(trained_scene, tmp_path: Path) -> None:
    scene, config_path = trained_scene
    data = without_semantics(scene, tmp_path / "data")
    label_main(LabelDatasetConfig(data=data, suggest_clicks=12, load_config=config_path, **NO_LABELS))
    path = data / "ssnerf_labels" / SUGGESTED_CLICKS
    clicks = json.loads(path.read_text())["clicks"]
    transforms = load_transforms(data)
    train = {frame["file_path"] for frame in training_frames(transforms)}
    assert len(clicks) == 12 and {click["file_path"] for click in clicks} <= train
    assert all(click["class"] is None and 0 <= click["x"] < 40 and 0 <= click["y"] < 30 for click in clicks)
    assert len({(c["file_path"], c["x"], c["y"]) for c in clicks}) == 12
    uncertainty = [click["uncertainty"] for click in clicks]
    assert uncertainty[0] == max(uncertainty)

    first, second = answered(data, scene, clicks[:8]), answered(data, scene, clicks[8:])
    first[1] = {**first[1], "class": None}  # skipped by the user
    path.write_text(json.dumps({"clicks": first}))
    label_main(LabelDatasetConfig(data=data, annotations=path, **NO_LABELS))
    expected: Dict[str, Dict] = {}
    for click in first:
        if click["class"] is not None:
            expected.setdefault(click["file_path"], {})[(click["y"], click["x"])] = click["class"]
    classes = json.loads((data / "transforms.json").read_text())["semantic_classes"]

    def check(labels: Dict[str, np.ndarray]) -> None:
        assert set(labels) == set(expected)
        for file_path, label in labels.items():
            pixels = {(int(r), int(c)): classes[label[r, c]] for r, c in zip(*np.nonzero(label != SEMANTIC_IGNORE))}
            assert pixels == expected[file_path]

    check(semantics_of(data))
    answers = data / "answers_2.json"
    answers.write_text(json.dumps({"clicks": second}))
    label_main(LabelDatasetConfig(data=data, annotations=answers, **NO_LABELS))
    for click in second:
        expected.setdefault(click["file_path"], {})[(click["y"], click["x"])] = click["class"]
    check(semantics_of(data))  # the first file's clicks stayed
    imports = json.loads((data / "transforms.json").read_text())["ssnerf_label"]["annotations"]
    assert [record["source"] for record in imports] == [str(path.resolve()), str(answers.resolve())]
    assert imports[0]["format"] == "clicks" and imports[0]["skipped_shapes"] == {"unanswered click": 1}


@pytest.mark.parametrize("content, words", [
    ('{"clicks": [{"file_path": "images/frame_00001.png", "x": 1, "y": 1, "class": "dragon"}]}',
     ["click 0", "'dragon' is not one of the dataset's classes", "--semantic-classes"]),
    ('{"clicks": [{"file_path": "images/frame_00001.png", "x": 40, "y": 1, "class": "wall"}]}',
     ["click 0", "pixel (40, 1) is outside", "40x30"]),
    ('{"clicks": [{"file_path": "images/elsewhere.png", "x": 1, "y": 1, "class": "wall"}]}',
     ["'images/elsewhere.png' matches no frame"]),
    ('{"clicks": [{"file_path": "images/frame_00001.png", "x": 1.5, "y": 1, "class": "wall"}]}',
     ["click 0 needs", "whole numbers"]),
    ('{"clicks": [{"file_path": "images/frame_00001.png", "x": 1, "y": 1, "class": "wall"}',
     ["not valid JSON"]),
])
def test_a_bad_answer_file_is_one_line_and_writes_nothing(trained_scene, tmp_path: Path, capsys, monkeypatch,
                                                         content: str, words: List[str]) -> None:
    scene, _ = trained_scene
    data = without_semantics(scene, tmp_path / "data")
    answers = tmp_path / "answers.json"
    answers.write_text(content)
    ssnerf_label_refuses(data, ["--annotations", str(answers), "--no-edges", "--no-keypoints", "--no-normals",
                                "--no-shading"], [str(answers), *words], capsys, monkeypatch)


def test_suggest_clicks_needs_a_model(walk: Path, tmp_path: Path, capsys, monkeypatch) -> None:
    data = shutil.copytree(walk, tmp_path / "data")
    ssnerf_label_refuses(data, ["--suggest-clicks", "5"], ["--suggest-clicks needs --load-config"], capsys,
                         monkeypatch)
