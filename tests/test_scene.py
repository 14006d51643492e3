"""Tests of the embedded scene generator (`ssnerf-make-scene`) and the label functions it uses."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Dict, Tuple

import cv2
import numpy as np
import pytest
import torch

from ssnerf_method.data.classes import CLASS_ID, SEMANTIC_CLASSES
from ssnerf_method.label_makers.keypoints import keypoint_response_map
from ssnerf_method.label_makers.normals import normals_from_depth
from ssnerf_method.label_makers.shading import lambertian_shading
from ssnerf_method.metrics import local_maxima
from ssnerf_method.properties import labelled_properties
from ssnerf_method.scene.make_scene import LABEL_DIRS, MakeSceneConfig, make_scene
from ssnerf_method.scene.room import build_room

WIDTH, HEIGHT, FRAMES = 48, 36, 6
LABEL_KEYS = ("depth", *(spec.name for spec in labelled_properties()))


def _generate(directory: Path, seed: int = 0, **overrides) -> Path:
    config = MakeSceneConfig(directory, width=WIDTH, height=HEIGHT, num_frames=FRAMES, seed=seed, test_every=3)
    for key, value in overrides.items():
        setattr(config, key, value)
    return make_scene(config)


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Tuple[Path, Dict]:
    path = _generate(tmp_path_factory.mktemp("scene"))
    return path.parent, json.loads(path.read_text())


def _read(root: Path, relative: str) -> np.ndarray:
    image = cv2.imread(str(root / relative), cv2.IMREAD_UNCHANGED)
    assert image is not None, relative
    if image.ndim == 2:
        return image
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB if image.shape[2] == 3 else cv2.COLOR_BGRA2RGBA)


def _intrinsics(meta: Dict) -> Tuple[float, float, float, float]:
    return meta["fl_x"], meta["fl_y"], meta["cx"], meta["cy"]


def _decode_normals(image: np.ndarray) -> np.ndarray:
    normals = image.astype(np.float64) / 255.0 * 2.0 - 1.0
    return normals / np.linalg.norm(normals, axis=-1, keepdims=True)


def _all_files(root: Path) -> Dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_layout_and_file_formats(scene):
    root, meta = scene
    assert meta["camera_model"] == "OPENCV"
    assert (meta["w"], meta["h"]) == (WIDTH, HEIGHT)
    assert all(meta[k] == 0 for k in ("k1", "k2", "p1", "p2"))
    hfov = np.rad2deg(2 * np.arctan(WIDTH / 2 / meta["fl_x"]))
    assert 70 <= hfov <= 80
    assert meta["semantic_classes"] == list(SEMANTIC_CLASSES)
    assert SEMANTIC_CLASSES[0] == "void" and len(SEMANTIC_CLASSES) == 14
    assert len({tuple(c) for c in meta["semantic_colors"]}) == len(SEMANTIC_CLASSES)
    assert meta["ssnerf_scene"]["generator"] == "ssnerf-make-scene" and meta["ssnerf_scene"]["seed"] == 0

    paths = [frame["file_path"] for frame in meta["frames"]]
    assert meta["test_filenames"] == meta["val_filenames"] == ["images/frame_00001.png", "images/frame_00004.png"]
    assert sorted(meta["train_filenames"] + meta["test_filenames"]) == sorted(paths)

    expected = {"depth": (np.uint16, 2), "semantics": (np.uint8, 2), "normals": (np.uint8, 3)}
    for frame in meta["frames"]:
        rgb = _read(root, frame["file_path"])
        assert rgb.shape == (HEIGHT, WIDTH, 3) and rgb.dtype == np.uint8
        assert np.asarray(frame["transform_matrix"]).shape == (4, 4)
        for key in LABEL_KEYS:
            relative = frame[f"{key}_file_path"]
            assert relative.startswith(f"{key}/")
            image = _read(root, relative)
            dtype, ndim = expected.get(key, (np.uint8, 2))
            assert image.dtype == dtype and image.ndim == ndim and image.shape[:2] == (HEIGHT, WIDTH), key
    written = {str(p.relative_to(root)) for p in root.rglob("*.png")}
    listed = {frame[k] for frame in meta["frames"] for k in frame if k.endswith("file_path")}
    assert written == listed


def test_deterministic_for_a_seed(scene, tmp_path):
    root, _ = scene
    reference = _all_files(root)
    assert _all_files(_generate(tmp_path / "same").parent) == reference
    other = _all_files(_generate(tmp_path / "other", seed=1).parent)
    assert other.keys() == reference.keys()
    assert other["images/frame_00000.png"] != reference["images/frame_00000.png"]
    assert other["transforms.json"] != reference["transforms.json"]


def test_refuses_non_empty_output_dir(scene, tmp_path):
    root, _ = scene
    with pytest.raises(FileExistsError, match="--overwrite"):
        _generate(root)
    (tmp_path / "stale").mkdir()
    (tmp_path / "stale" / "images").mkdir()
    (tmp_path / "stale" / "images" / "frame_99999.png").write_bytes(b"old")
    (tmp_path / "stale" / "notes.txt").write_text("kept")
    _generate(tmp_path / "stale", overwrite=True)
    assert not (tmp_path / "stale" / "images" / "frame_99999.png").exists()
    assert (tmp_path / "stale" / "notes.txt").exists()
    assert all((tmp_path / "stale" / name).is_dir() for name in LABEL_DIRS)


def test_normals_from_depth_match_rendered_normals(scene):
    root, meta = scene
    errors = []
    for frame in meta["frames"]:
        depth = _read(root, frame["depth_file_path"]).astype(np.float64) / 1000.0
        assert depth.min() > 0
        rendered = _decode_normals(_read(root, frame["normals_file_path"]))
        derived = normals_from_depth(depth, *_intrinsics(meta))
        # Away from edges and creases: the rendered normal is constant over the pixel's 3x3 neighbourhood.
        flat = np.ones(depth.shape, dtype=bool)
        padded = np.pad(rendered, ((1, 1), (1, 1), (0, 0)), mode="edge")
        for dy in range(3):
            for dx in range(3):
                neighbour = padded[dy : dy + HEIGHT, dx : dx + WIDTH]
                flat &= np.einsum("hwc,hwc->hw", neighbour, rendered) > np.cos(np.deg2rad(2.0))
        usable = flat & np.isfinite(derived).all(axis=-1)
        assert usable.mean() > 0.3
        cosine = np.clip(np.einsum("nc,nc->n", derived[usable], rendered[usable]), -1.0, 1.0)
        errors.append(np.rad2deg(np.arccos(cosine)))
        # Normals face the camera: dot(n, -view) > 0 for every pixel.
        assert (_read(root, frame["shading_file_path"]) > 0).mean() > 0.95
    assert np.median(np.concatenate(errors)) < 3.0


def test_normals_from_depth_marks_discontinuities_and_invalid_depth():
    fx = fy = 40.0
    depth = np.full((20, 20), 2.0)
    depth[:, 10:] = 4.0
    depth[0, 0] = 0.0
    normals = normals_from_depth(depth, fx, fy, 10.0, 10.0)
    assert np.isnan(normals[0, 0]).all()
    interior = normals[2:-2, 2:8]
    np.testing.assert_allclose(interior, np.broadcast_to([0.0, 0.0, 1.0], interior.shape), atol=1e-9)
    # Pixels on both sides of the step keep a one-sided difference and stay fronto-parallel.
    np.testing.assert_allclose(normals[5, 9], [0.0, 0.0, 1.0], atol=1e-9)
    np.testing.assert_allclose(normals[5, 10], [0.0, 0.0, 1.0], atol=1e-9)


def test_semantics_in_class_list_and_varied(scene):
    root, meta = scene
    seen = set()
    for frame in meta["frames"]:
        semantics = _read(root, frame["semantics_file_path"])
        assert semantics.max() < len(SEMANTIC_CLASSES)
        assert (semantics != CLASS_ID["void"]).all()
        seen |= set(np.unique(semantics).tolist())
    assert len(seen) >= 8, [SEMANTIC_CLASSES[i] for i in sorted(seen)]


def test_shading_is_lambertian_of_written_normals(scene):
    root, meta = scene
    for frame in meta["frames"]:
        normals = _decode_normals(_read(root, frame["normals_file_path"]))
        expected = lambertian_shading(normals, *_intrinsics(meta))
        shading = _read(root, frame["shading_file_path"]) / 255.0
        assert np.abs(shading - expected).max() < 0.03


def test_edges_are_non_trivial(scene):
    root, meta = scene
    fractions = []
    for frame in meta["frames"]:
        edges = _read(root, frame["edges_file_path"])
        assert set(np.unique(edges).tolist()) <= {0, 255}
        fractions.append((edges > 0).mean())
    assert 0.01 < np.mean(fractions) < 0.4


def test_keypoint_label_is_the_response_map_of_the_written_rgb(scene):
    """The scene's keypoint label is `keypoint_response_map` of its own 8-bit RGB (quantised as written), with
    local maxima above 0.5 (the metric's keypoints) in the views."""
    root, meta = scene
    peaks = 0
    for frame in meta["frames"]:
        label = _read(root, frame["keypoints_file_path"])
        expected = np.round(keypoint_response_map(_read(root, frame["file_path"])) * 255)
        np.testing.assert_array_equal(label, expected)
        peaks += len(local_maxima(torch.from_numpy(label / 255.0), torch.ones(label.shape, dtype=torch.bool), 0.5)[0])
    assert peaks > 0
    assert "SURF blob-response map" in meta["ssnerf_scene"]["keypoints"]


def test_pose_projects_known_points_onto_matching_depth(scene):
    """Centres of wall-mounted objects project, with the written intrinsics and poses, onto their depth and class."""
    root, meta = scene
    room = build_room(0)
    fx, fy, cx, cy = _intrinsics(meta)
    checked = 0
    for name, axis in (("painting_back", 2), ("painting_left", 0), ("window", 0), ("tv", 2)):
        primitive = room.primitive(name)
        lo, hi = primitive.shape.bounds
        point = (lo + hi) / 2
        point[axis] = hi[axis] if name in ("painting_back", "painting_left") else lo[axis]  # the face into the room
        for frame in meta["frames"]:
            world_to_camera = np.linalg.inv(np.asarray(frame["transform_matrix"]))
            x, y, z = world_to_camera[:3, :3] @ point + world_to_camera[:3, 3]
            if z >= 0:
                continue
            col, row = int(np.floor(fx * x / -z + cx)), int(np.floor(-fy * y / -z + cy))
            if not (2 <= col < WIDTH - 2 and 2 <= row < HEIGHT - 2):
                continue
            depth = _read(root, frame["depth_file_path"])[row, col] / 1000.0
            assert abs(depth - (-z)) < 0.05, (name, frame["file_path"], depth, -z)
            assert _read(root, frame["semantics_file_path"])[row, col] == primitive.semantic_id
            checked += 1
    assert checked >= 2


def test_walkthrough_is_as_sparse_as_the_paper_split_and_stays_in_the_room() -> None:
    from ssnerf_method.data.spacing import pose_spacing
    from ssnerf_method.scene.make_scene import camera_path

    config = MakeSceneConfig(Path("unused"), trajectory="walkthrough")
    assert (config.num_frames, config.test_every, config.test_offset) == (50, 8, 0)  # the authors' llffhold = 8
    poses = np.stack(camera_path("walkthrough", 50, 0))
    held_out = np.arange(50) % 8 == 0
    assert held_out.sum() == 7
    walk = pose_spacing(poses[~held_out], poses[held_out])
    loop_poses = np.stack(camera_path("loop", 60, 0))
    loop_held_out = np.arange(60) % 5 == 2
    loop = pose_spacing(loop_poses[~loop_held_out], loop_poses[loop_held_out])
    assert walk["median_m"] > 3 * loop["median_m"] and walk["median_deg"] > loop["median_deg"]
    centres = poses[:, :3, 3]
    assert np.all(np.abs(centres[:, 0]) < 2.8) and np.all(np.abs(centres[:, 2]) < 2.3)  # clear of the walls
    assert centres[:, 1].min() > 1.15 and np.ptp(centres[:, 1]) > 0.3  # above the low furniture, varying height
    steps = np.linalg.norm(np.diff(centres, axis=0), axis=1)
    assert steps.max() < 2 * np.median(steps)  # evenly spaced along the walk: no jumps
    assert not np.array_equal(poses, np.stack(camera_path("walkthrough", 50, 1)))  # the seed moves the walk


def test_normals_from_depth_label_matches_the_geometry_and_leaves_discontinuities_unlabelled(tmp_path: Path) -> None:
    exact_root = _generate(tmp_path / "exact", trajectory="walkthrough").parent
    derived_root = _generate(tmp_path / "derived", trajectory="walkthrough", normals="from-depth").parent
    meta = json.loads((derived_root / "transforms.json").read_text())
    assert meta["ssnerf_scene"]["normals"].startswith("from depth by finite differences")
    angles, unlabelled = [], []
    for frame in meta["frames"]:
        derived = _read(derived_root, frame["normals_file_path"])
        assert derived.shape[:2] == (HEIGHT, WIDTH) and derived.shape[2] in (3, 4)  # alpha where some are unlabelled
        exact = _decode_normals(_read(exact_root, frame["normals_file_path"]))
        labelled = derived[..., 3] > 0 if derived.shape[2] == 4 else np.ones((HEIGHT, WIDTH), dtype=bool)
        cosine = np.clip((_decode_normals(derived[..., :3]) * exact).sum(axis=-1), -1.0, 1.0)
        angles.append(np.degrees(np.arccos(cosine[labelled])))
        unlabelled.append(1.0 - labelled.mean())
        assert (_read(exact_root, frame["depth_file_path"]) == _read(derived_root, frame["depth_file_path"])).all()
    angles = np.concatenate(angles)
    assert np.median(angles) < 2.0 and np.mean(angles > 20.0) < 0.2  # follow the surfaces; off at edges (48x36 px)
    assert 0.0 < np.mean(unlabelled) < 0.2
    from ssnerf_method.data.validate import validate_dataset

    assert validate_dataset(derived_root).faults == []
