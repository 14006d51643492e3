"""`ssnerf-label` on small nerfstudio datasets: with depth (the default scene stripped of its labels), without depth (an
`ns-process-data`-like capture that then trains), semantics given as ids or colours, provenance, output elsewhere and
a read-only dataset (the bad-input cases are `test_validation.py`'s)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Dict

import cv2
import numpy as np
import pytest
from PIL import Image

from ssnerf_method.cli.label import main
from ssnerf_method.data.dataparser import SSNeRFDataParserConfig
from ssnerf_method.data.dataset import SSNeRFDataset
from ssnerf_method.data.io import DatasetInputError
from ssnerf_method.data.transforms import load_transforms
from ssnerf_method.label_makers import canny_edges
from ssnerf_method.label_makers.keypoints import keypoint_response_map
from ssnerf_method.label_makers.makers import LabelOptions
from ssnerf_method.label_tool.label_dataset import KEPT, LABELLED, LabelDatasetConfig, label_dataset
from ssnerf_method.label_tool.paths import LABEL_FOLDER
from ssnerf_method.properties import OPTIONAL_PROPERTIES, REGISTRY
from ssnerf_method.scene.make_scene import MakeSceneConfig, make_scene

from conftest import look_at
from test_training import lite_config, train

DERIVED = ("normals", "shading", "edges", "keypoints")
NO_DEPTH = "no depth_file_path (ssnerf-label's depth model renders it unless --depth-model-steps 0)"


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("scene") / "scene"
    make_scene(MakeSceneConfig(output_dir=root, width=64, height=48, num_frames=5))
    return root


def strip_labels(scene: Path, target: Path, keep_depth: bool = True) -> Path:
    """A copy of the scene whose transforms list images (and depth) only; the true labels stay on disk."""
    shutil.copytree(scene, target)
    meta = json.loads((target / "transforms.json").read_text())
    for frame in meta["frames"]:
        for name in OPTIONAL_PROPERTIES:
            frame.pop(REGISTRY[name].file_key)
        if not keep_depth:
            frame.pop("depth_file_path")
    (target / "transforms.json").write_text(json.dumps(meta))
    return target


def run(data: Path, **options) -> object:
    config = LabelDatasetConfig(data=data, workers=1, **options)
    return label_dataset(config, load_transforms(data))


def snapshot(folder: Path) -> Dict[str, bytes]:
    return {str(path.relative_to(folder)): path.read_bytes() for path in sorted(folder.rglob("*")) if path.is_file()}


def read(path: Path) -> np.ndarray:
    return np.asarray(Image.open(path))


def decode_normals(encoded: np.ndarray) -> np.ndarray:
    normals = encoded[..., :3].astype(np.float64) / 255.0 * 2.0 - 1.0
    return normals / np.linalg.norm(normals, axis=-1, keepdims=True)


def test_with_depth_derives_every_label_and_keeps_the_original(scene: Path, tmp_path: Path) -> None:
    data = strip_labels(scene, tmp_path / "data")
    original = (data / "transforms.json").read_bytes()
    report = run(data)
    assert all(report.outcomes[name] == {LABELLED: 5} for name in DERIVED)
    assert report.outcomes["semantics"] == {"skipped: not given (semantics are never derived; pass --annotations)": 5}
    assert (data / "transforms.json.orig").read_bytes() == original
    assert not list(data.glob(".ssnerf-staging-*"))

    meta = json.loads((data / "transforms.json").read_text())
    truth = json.loads((scene / "transforms.json").read_text())
    assert meta["semantic_classes"] == truth["semantic_classes"]  # everything else is carried over
    angles, shading_errors = [], []
    for frame, true_frame in zip(meta["frames"], truth["frames"]):
        image = read(data / frame["file_path"])
        for name in DERIVED:
            assert frame[REGISTRY[name].file_key] == f"{LABEL_FOLDER}/{name}/{Path(frame['file_path']).name}"
        np.testing.assert_array_equal(read(data / frame["edges_file_path"]), canny_edges(image) * 255)
        expected = np.round(keypoint_response_map(image) * 255)  # SURF's response map
        np.testing.assert_array_equal(read(data / frame["keypoints_file_path"]), expected)
        derived = read(data / frame["normals_file_path"])
        labelled = derived[..., 3] > 0 if derived.shape[-1] == 4 else np.ones(derived.shape[:2], bool)
        assert labelled.mean() > 0.8  # only depth discontinuities are unlabelled
        true_normals = decode_normals(read(scene / true_frame["normals_file_path"]))
        cosine = np.einsum("hwc,hwc->hw", decode_normals(derived), true_normals)[labelled]
        angles.append(np.rad2deg(np.arccos(np.clip(cosine, -1, 1))))
        shading = read(data / frame["shading_file_path"]).astype(float)
        shading = shading[..., 0] if shading.ndim == 3 else shading  # grey+alpha where normals are unlabelled
        true_shading = read(scene / true_frame["shading_file_path"]).astype(float)
        shading_errors.append(np.abs(shading - true_shading)[labelled] / 255.0)
    assert np.median(np.concatenate(angles)) < 3.0
    assert np.median(np.concatenate(shading_errors)) < 0.03

    # The labelled dataset loads: every derived property is available and valid on most pixels.
    outputs = SSNeRFDataParserConfig(data=data).setup().get_dataparser_outputs("train")
    assert set(outputs.metadata["available_properties"]) == {*DERIVED, "semantics"}  # declared classes train (strokes)
    item = SSNeRFDataset(outputs)[0]
    for name in DERIVED:
        assert REGISTRY[name].kind.valid(item[name]).float().mean() > 0.8

    # Running again keeps every label and the true original backup.
    before = snapshot(data)
    again = run(data)
    assert all(again.outcomes[name] == {KEPT: 5} for name in DERIVED)
    after = snapshot(data)
    assert after.pop("transforms.json") != b"" and before.pop("transforms.json") != b""
    assert after == before


def test_low_resolution_npy_depth_like_record3d(scene: Path, tmp_path: Path) -> None:
    """Phone captures (ns-process-data record3d/polycam) give depth as .npy in metres at a lower resolution than the
    images: normals are derived at the depth's resolution and mapped to the image's pixels."""
    data = strip_labels(scene, tmp_path / "data")
    meta = json.loads((data / "transforms.json").read_text())
    for frame in meta["frames"]:
        depth = read(data / frame["depth_file_path"]).astype(np.float32) / 1000.0
        path = Path(frame["depth_file_path"]).with_suffix(".npy")
        np.save(data / path, depth[::2, ::2])
        frame["depth_file_path"] = str(path)
    (data / "transforms.json").write_text(json.dumps(meta))
    report = run(data, edges=False, keypoints=False)
    assert report.outcomes["normals"] == {LABELLED: 5}
    truth = json.loads((scene / "transforms.json").read_text())
    angles = []
    for frame, true_frame in zip(json.loads((data / "transforms.json").read_text())["frames"], truth["frames"]):
        derived = read(data / frame["normals_file_path"])
        assert derived.shape[:2] == (48, 64)
        labelled = derived[..., 3] > 0 if derived.shape[-1] == 4 else np.ones(derived.shape[:2], bool)
        true_normals = decode_normals(read(scene / true_frame["normals_file_path"]))
        cosine = np.einsum("hwc,hwc->hw", decode_normals(derived), true_normals)[labelled]
        angles.append(np.rad2deg(np.arccos(np.clip(cosine, -1, 1))))
    assert np.median(np.concatenate(angles)) < 5.0


def test_switches_and_new_output_file(scene: Path, tmp_path: Path) -> None:
    data = strip_labels(scene, tmp_path / "data")
    before = snapshot(data)
    report = run(data, output="transforms_labelled.json", keypoints=False, shading=False,
                 label_options=LabelOptions(canny_low=20, canny_high=40))
    assert set(report.outcomes) == {"semantics", "normals", "edges"}
    assert snapshot(data)["transforms.json"] == before["transforms.json"]
    assert not (data / "transforms.json.orig").exists()
    meta = json.loads((data / "transforms_labelled.json").read_text())
    frame = meta["frames"][0]
    assert "keypoints_file_path" not in frame and "shading_file_path" not in frame
    edges = read(data / frame["edges_file_path"])
    np.testing.assert_array_equal(edges, canny_edges(read(data / frame["file_path"]), 20, 40) * 255)
    assert meta["ssnerf_label"]["edges"].startswith("Canny, thresholds 20 / 40")
    with pytest.raises(DatasetInputError, match="transforms_labelled.json: exists"):
        run(data, output="transforms_labelled.json")


def test_given_normals_are_kept_and_shaded(scene: Path, tmp_path: Path) -> None:
    """A frame that already lists normals (e.g. from an outside annotator) keeps them; shading is made from them."""
    data = strip_labels(scene, tmp_path / "data", keep_depth=False)
    meta = json.loads((data / "transforms.json").read_text())
    meta["frames"][0]["normals_file_path"] = "normals/frame_00000.png"
    (data / "transforms.json").write_text(json.dumps(meta))
    report = run(data)
    assert report.outcomes["normals"] == {KEPT: 1, f"skipped: {NO_DEPTH}": 4}
    assert report.outcomes["shading"] == {LABELLED: 1, "skipped: no normals (given or derived from depth)": 4}
    frame = json.loads((data / "transforms.json").read_text())["frames"][0]
    assert frame["normals_file_path"] == "normals/frame_00000.png"
    shading = read(data / frame["shading_file_path"]).astype(float)
    np.testing.assert_allclose(shading, read(scene / "shading/frame_00000.png"), atol=2)


def test_semantics_from_ids_and_from_colours(scene: Path, tmp_path: Path) -> None:
    data = strip_labels(scene, tmp_path / "data")
    meta = json.loads((scene / "transforms.json").read_text())
    (tmp_path / "ids").mkdir()
    (tmp_path / "colours").mkdir()
    for frame in meta["frames"][:3]:  # two frames have no given semantics
        ids = read(scene / frame["semantics_file_path"])
        name = Path(frame["file_path"]).name
        Image.fromarray(ids.astype(np.uint16)).save(tmp_path / "ids" / name)  # 16-bit ids are accepted
        colours = np.array(meta["semantic_colors"], dtype=np.uint8)[ids]
        Image.fromarray(colours).save(tmp_path / "colours" / name)
    for source in ("ids", "colours"):
        target = tmp_path / f"labelled_{source}"
        shutil.copytree(data, target)
        report = run(target, semantics_dir=tmp_path / source, normals=False, shading=False, edges=False,
                     keypoints=False)
        assert report.outcomes["semantics"] == {LABELLED: 3, f"skipped: no file in {tmp_path / source}": 2}
        labelled = json.loads((target / "transforms.json").read_text())
        assert labelled["semantic_classes"] == meta["semantic_classes"]
        for frame, truth in zip(labelled["frames"][:3], meta["frames"]):
            np.testing.assert_array_equal(read(target / frame["semantics_file_path"]),
                                          read(scene / truth["semantics_file_path"]))


def write_capture(root: Path, num_frames: int = 6) -> Path:
    """An `ns-process-data images`-like folder: JPEGs, an OPENCV camera with distortion, no depth, no labels."""
    (root / "images").mkdir(parents=True)
    rng = np.random.default_rng(0)
    frames = []
    for index in range(num_frames):
        image = np.full((24, 32, 3), 40, dtype=np.uint8)
        x = 4 + 3 * index
        image[6:18, x : x + 10] = rng.integers(150, 255, 3)
        cv2.imwrite(str(root / "images" / f"frame_{index + 1:05d}.jpg"), image)
        angle = 0.3 * index
        c2w = np.eye(4)
        c2w[:3, :3] = [[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]]
        c2w[:3, 3] = [2 * np.sin(angle), 0.1, 2 * np.cos(angle)]
        frames.append({"file_path": f"images/frame_{index + 1:05d}.jpg", "transform_matrix": c2w.tolist(),
                       "colmap_im_id": index + 1})
    transforms = {
        "w": 32, "h": 24, "fl_x": 30.0, "fl_y": 30.0, "cx": 16.0, "cy": 12.0,
        "k1": -0.05, "k2": 0.01, "p1": 0.0, "p2": 0.0, "camera_model": "OPENCV",
        "frames": frames,
        "applied_transform": [[1, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0]],
        "ply_file_path": "sparse_pc.ply",
    }
    (root / "transforms.json").write_text(json.dumps(transforms, indent=4))
    return root


def test_capture_without_depth_labels_edges_and_keypoints_then_trains(tmp_path: Path) -> None:
    data = write_capture(tmp_path / "capture")
    report = main(LabelDatasetConfig(data=data, depth_model_steps=0))  # (the depth model: tests/test_depth_from.py)
    assert report.outcomes["edges"] == {LABELLED: 6} and report.outcomes["keypoints"] == {LABELLED: 6}
    assert report.outcomes["normals"] == {f"skipped: {NO_DEPTH}": 6}
    assert report.outcomes["shading"] == {"skipped: no normals (given or derived from depth)": 6}
    meta = json.loads((data / "transforms.json").read_text())
    assert meta["ply_file_path"] == "sparse_pc.ply" and meta["applied_transform"][1] == [0, 0, 1, 0]
    assert meta["frames"][0]["edges_file_path"] == f"{LABEL_FOLDER}/edges/frame_00001.png"

    config = lite_config(data, tmp_path / "outputs", iterations=3)
    config.steps_per_save = 10**6
    _, totals, dicts = train(config)
    assert len(totals) == 3 and np.isfinite(totals).all()
    assert {"rgb_loss", "edges_loss", "keypoints_loss"} <= set(dicts[0])
    assert not {"normals_loss", "shading_loss", "semantics_loss"} & set(dicts[0])  # not derivable: not trained


def test_blender_folder_gets_a_nerfstudio_transforms(tmp_path: Path) -> None:
    """A Blender-synthetic folder (transforms_{train,val,test}.json, RGBA images, camera_angle_x) is read as
    nerfstudio's blender-data reads it; the labels go into a new transforms.json that our dataparser trains from."""
    root = tmp_path / "lego"
    for split, count in (("train", 3), ("val", 1), ("test", 2)):
        (root / split).mkdir(parents=True)
        frames = []
        for index in range(count):
            rgba = np.zeros((20, 24, 4), dtype=np.uint8)
            rgba[5:15, 6 + index : 16 + index] = (200, 120, 40, 255)
            Image.fromarray(rgba, mode="RGBA").save(root / split / f"r_{index}.png")
            c2w = look_at(np.array([np.cos(index), np.sin(index), 0.5]) * 3, np.zeros(3))
            frames.append({"file_path": f"./{split}/r_{index}", "rotation": 0.03, "transform_matrix": c2w.tolist()})
        (root / f"transforms_{split}.json").write_text(json.dumps({"camera_angle_x": 0.69, "frames": frames}))
    before = snapshot(root)
    report = run(root)
    assert report.outcomes["edges"] == {LABELLED: 6} and report.backup_path is None
    after = snapshot(root)
    assert all(after[name] == content for name, content in before.items())  # the Blender files are untouched
    meta = json.loads(after["transforms.json"])
    assert meta["test_filenames"] == ["test/r_0.png", "test/r_1.png"] and meta["val_filenames"] == ["val/r_0.png"]
    assert meta["fl_x"] == pytest.approx(0.5 * 24 / np.tan(0.5 * 0.69)) and (meta["w"], meta["h"]) == (24, 20)
    outputs = SSNeRFDataParserConfig(data=root).setup().get_dataparser_outputs("test")
    assert [Path(path).name for path in outputs.image_filenames] == ["r_0.png", "r_1.png"]
    assert "edges" in outputs.metadata["available_properties"]


def test_provenance_only_for_the_labels_it_made(scene: Path, tmp_path: Path) -> None:
    """Given normals are kept and not claimed; labels made on an earlier run keep their record."""
    data = strip_labels(scene, tmp_path / "data", keep_depth=False)
    meta = json.loads((data / "transforms.json").read_text())
    for frame in meta["frames"]:
        frame["normals_file_path"] = frame["file_path"].replace("images/", "normals/")
    (data / "transforms.json").write_text(json.dumps(meta))
    run(data, keypoints=False, shading=False)
    record = json.loads((data / "transforms.json").read_text())["ssnerf_label"]
    assert set(record) == {"tool", "edges"}
    run(data, edges=False, shading=False)
    assert set(json.loads((data / "transforms.json").read_text())["ssnerf_label"]) == {"tool", "edges", "keypoints"}


def test_output_in_another_folder_points_back_at_the_data(scene: Path, tmp_path: Path) -> None:
    """`--output elsewhere/transforms.json`: labels beside it, every other path rewritten; the dataset untouched."""
    data = strip_labels(scene, tmp_path / "data")
    before = snapshot(data)
    report = run(data, output=str(tmp_path / "labelled" / "transforms.json"), keypoints=False)
    assert snapshot(data) == before
    meta = json.loads((tmp_path / "labelled" / "transforms.json").read_text())
    assert meta["frames"][0]["file_path"] == "../data/images/frame_00000.png"
    assert meta["frames"][0]["edges_file_path"].startswith(LABEL_FOLDER)
    assert meta["test_filenames"][0].startswith("../data/images/")
    outputs = SSNeRFDataParserConfig(data=tmp_path / "labelled").setup().get_dataparser_outputs("train")
    assert set(outputs.metadata["available_properties"]) == {"normals", "shading", "edges", "semantics"}
    assert report.transforms_path == tmp_path / "labelled" / "transforms.json"


def test_read_only_dataset_suggests_output_elsewhere(scene: Path, tmp_path: Path, monkeypatch) -> None:
    """The first write into a read-only folder (made to fail here: root may write anywhere) gives one line."""
    import ssnerf_method.data.io as io

    data = strip_labels(scene, tmp_path / "data")
    before = snapshot(data)

    def refuse(prefix: str, dir: Path) -> str:
        raise PermissionError(13, "Permission denied", str(dir))

    monkeypatch.setattr(io.tempfile, "mkdtemp", refuse)
    expected = f"{data}: cannot write there.*--output /writable/folder/transforms.json"
    with pytest.raises(DatasetInputError, match=expected):
        run(data)
    assert snapshot(data) == before


def test_cli_prints_one_line_and_exits_1(tmp_path: Path) -> None:
    result = subprocess.run(
        [sys.executable, "-m", "ssnerf_method.cli.label", str(tmp_path / "missing")],
        capture_output=True, text=True, timeout=120,
    )
    assert result.returncode == 1
    assert result.stderr.strip().splitlines()[-1] == f"ssnerf-label: {tmp_path / 'missing'}: not a folder. Point at " \
        "the dataset folder that holds transforms.json."
    assert "Traceback" not in result.stderr
