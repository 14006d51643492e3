"""Tiny datasets in the two source layouts `ssnerf-import` reads, written from arrays (no committed binaries).

Each writer defines its cameras in the SOURCE's own convention and projects a known 3D point with the source's own
camera model, written out here independently of the importers, so a test can check that the imported nerfstudio
cameras put that point on the same pixels.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from PIL import Image

WIDTH, HEIGHT = 16, 12
"""Image size the tests train on."""

LANDMARK = np.array([0.12, -0.07, 0.1])
"""A world point near the centre every fixture camera looks at."""

LLFF_NORMAL = (200, 100, 230)
"""Constant normals-map pixel written in the paper's encoding (LUB axes)."""

LLFF_LABEL_IDS = (11, 4)
"""Class ids in the upper / lower half of each label map (default names: 11 = wall, 4 = floor)."""

REPLICA_CLASSES = {0: "undefined", 3: "wall", 40: "floor", 93: "sofa", 7: "book", 99: "zz-mystery", 50: "bed"}
"""The fixture's info_semantic.json; ids 0, 3, 40, 93, 7 and 99 appear in its semantic maps (50 does not)."""

REPLICA_IDS_PRESENT = (0, 3, 7, 40, 93, 99)

WORLD_UP = np.array([0.0, 0.0, 1.0])
"""World up of the fixture scenes (z up)."""


@dataclass
class SourceFixture:
    """A written source dataset and what its own camera model says about it."""

    root: Path
    num_frames: int
    pixels: dict[int, tuple[float, float]] = field(default_factory=dict)
    """Frame index -> (x, y) continuous pixel position of `LANDMARK` (pixel (i, j) spans [i, i + 1) x [j, j + 1))."""


def _save(path: Path, array: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(array).save(path)


def _gradient_rgb(width: int, height: int, shift: float) -> np.ndarray:
    rows = np.linspace(0.0, 1.0, height)[:, None] * np.ones((1, width))
    rgb = np.stack([0.8 - 0.3 * rows, 0.2 + 0.2 * rows, np.full_like(rows, 0.1 + shift)], axis=-1)
    return np.round(np.clip(rgb, 0, 1) * 255).astype(np.uint8)


def _ring(num_frames: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """(position, unit forward) of cameras on a tilted ring around the origin, each looking at the origin."""
    cameras = []
    for i in range(num_frames):
        angle = 2 * np.pi * i / num_frames
        position = np.array([2.0 * np.cos(angle), 2.0 * np.sin(angle), 0.6 + 0.2 * np.sin(3 * angle)])
        cameras.append((position, -position / np.linalg.norm(position)))
    return cameras


# --------------------------------------------------------------------------------------------------------------------
# The paper's LLFF layout


def llff_rotation(forward: np.ndarray) -> np.ndarray:
    """LLFF camera-to-world rotation: columns are the camera's down, right and backwards axes in world coordinates."""
    right = np.cross(forward, WORLD_UP)
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    return np.stack([down, right, -forward], axis=1)


def llff_project(point: np.ndarray, rotation: np.ndarray, position: np.ndarray, focal: float, width: int,
                 height: int) -> tuple[float, float]:  # fmt: skip
    """LLFF pinhole: camera coordinates (down, right, backwards); the camera looks along -backwards."""
    down, right, backwards = rotation.T @ (point - position)
    depth = -backwards
    return width / 2 + focal * right / depth, height / 2 + focal * down / depth


def write_paper_llff(
    root: Path,
    num_frames: int = 10,
    width: int = WIDTH,
    height: int = HEIGHT,
    pose_scale: int = 4,
    normals_folder: str = "normal_new",
    label_folders: Sequence[str] = ("label", "reshading", "keypoint", "edge"),
    landmark_frames: Sequence[int] = (3, 8),
) -> SourceFixture:
    """Write a scene as the SS-NeRF authors released theirs: images/000.png ..., label folders, poses_bounds.npy.

    The pose file's hwf is at `pose_scale` times the images' resolution (as LLFF pose files at full resolution beside
    downsampled images). Labels: normals the constant `LLFF_NORMAL`; label/ 3-channel with class ids in channel 0
    (`LLFF_LABEL_IDS`, other channels 99); reshading/ 3-channel with a gradient in channel 0 only; keypoint/ and edge/
    single-channel constants.
    """
    fixture = SourceFixture(root, num_frames)
    focal_full = 0.9 * width * pose_scale
    hwf = np.array([height * pose_scale, width * pose_scale, focal_full])
    rows = []
    upper = np.arange(height)[:, None] < height // 2
    for i, (position, forward) in enumerate(_ring(num_frames)):
        rotation = llff_rotation(forward)
        pose = np.concatenate([rotation, position[:, None], hwf[:, None]], axis=1)
        rows.append(np.concatenate([pose.reshape(-1), [0.5, 6.0]]))
        if i in landmark_frames:
            fixture.pixels[i] = llff_project(LANDMARK, rotation, position, focal_full / pose_scale, width, height)
        name = f"{i:03d}.png"
        _save(root / "images" / name, _gradient_rgb(width, height, 0.02 * i))
        if normals_folder:
            _save(root / normals_folder / name, np.broadcast_to(np.uint8(LLFF_NORMAL), (height, width, 3)).copy())
        if "label" in label_folders:
            ids = np.where(upper, *LLFF_LABEL_IDS) * np.ones((1, width))
            _save(
                root / "label" / name,
                np.stack([ids, np.full_like(ids, 99), np.full_like(ids, 99)], -1).astype(np.uint8),
            )
        if "reshading" in label_folders:
            shade = np.linspace(150, 250, width)[None, :] * np.ones((height, 1))
            _save(root / "reshading" / name, np.stack([shade, shade * 0, shade * 0 + 7], -1).astype(np.uint8))
        if "keypoint" in label_folders:
            _save(root / "keypoint" / name, np.full((height, width), 40, dtype=np.uint8))
        if "edge" in label_folders:
            _save(root / "edge" / name, np.full((height, width), 20, dtype=np.uint8))
    np.save(root / "poses_bounds.npy", np.array(rows))
    return fixture


# --------------------------------------------------------------------------------------------------------------------
# Semantic-NeRF's Replica renders


def opencv_camera_to_world(position: np.ndarray, forward: np.ndarray) -> np.ndarray:
    """4x4 camera-to-world with OpenCV axes: columns right, down, forward, position."""
    right = np.cross(forward, WORLD_UP)
    right /= np.linalg.norm(right)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = right, np.cross(forward, right), forward, position
    return pose


def replica_project(point: np.ndarray, camera_to_world: np.ndarray, width: int, height: int) -> tuple[float, float]:
    """Semantic-NeRF's Replica camera: OpenCV pinhole, 90 degree horizontal field of view, centred principal point."""
    x, y, z = camera_to_world[:3, :3].T @ (point - camera_to_world[:3, 3])
    focal = width / 2.0 / np.tan(np.pi / 4)
    return width / 2 + focal * x / z, height / 2 + focal * y / z


def replica_semantics(width: int, height: int, shift: int) -> np.ndarray:
    """(H, W) uint8 Replica class ids: vertical stripes of `REPLICA_IDS_PRESENT`, rolled by `shift` columns."""
    columns = np.array(REPLICA_IDS_PRESENT)[np.arange(width) * len(REPLICA_IDS_PRESENT) // width]
    return np.roll(np.broadcast_to(columns, (height, width)), shift, axis=1).astype(np.uint8)


def write_semantic_nerf(
    root: Path,
    num_frames: int = 20,
    width: int = 2 * WIDTH,
    height: int = 2 * HEIGHT,
    with_info: bool = True,
    landmark_frames: Sequence[int] = (5, 12),
) -> SourceFixture:
    """Write a sequence as Semantic-NeRF's Replica renders: rgb/, depth/, semantic_class/, traj_w_c.txt.

    Depth of frame N is the constant 1500 + N mm; semantics are `replica_semantics`; with `with_info` the sequence
    folder holds an info_semantic.json naming `REPLICA_CLASSES`.
    """
    fixture = SourceFixture(root, num_frames)
    lines = []
    for i, (position, forward) in enumerate(_ring(num_frames)):
        pose = opencv_camera_to_world(position, forward)
        lines.append(" ".join(f"{value:.17g}" for value in pose.reshape(-1)))
        if i in landmark_frames:
            fixture.pixels[i] = replica_project(LANDMARK, pose, width, height)
        _save(root / "rgb" / f"rgb_{i}.png", _gradient_rgb(width, height, 0.02 * i))
        _save(root / "depth" / f"depth_{i}.png", np.full((height, width), 1500 + i, dtype=np.uint16))
        _save(root / "semantic_class" / f"semantic_class_{i}.png", replica_semantics(width, height, i % 3))
    (root / "traj_w_c.txt").write_text("\n".join(lines) + "\n")
    if with_info:
        classes = [{"id": key, "name": name} for key, name in REPLICA_CLASSES.items()]
        (root / "info_semantic.json").write_text(json.dumps({"classes": classes, "id_to_label": []}))
    return fixture
