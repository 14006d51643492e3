"""`ssnerf-make-scene OUT_DIR`: render the embedded default SS-NeRF scene as a nerfstudio dataset with property labels.

A camera walks a smooth closed loop inside the procedural room (`room.py`), looking outwards and around with slight
tilts. Each frame gets an anti-aliased RGB image (2x2 supersampling) and, at pixel centres, z-depth, semantics and
camera-frame normals from the ray caster; shading, keypoint and edge labels come from `ssnerf_method.labels` (shading
from the true normals, keypoints and edges from the written 8-bit RGB). Output is deterministic for a seed.
"""

from __future__ import annotations

import json
import shutil
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List

import cv2
import numpy as np
import tyro

from ssnerf_method.data.camera_path import to_model_frame, write_camera_path
from ssnerf_method.data.dataparser import SSNeRFDataParserConfig
from ssnerf_method.labels.edges import canny_edges
from ssnerf_method.labels.keypoints import Detector, KeypointLabel, describe_keypoint_label, keypoint_label
from ssnerf_method.labels.shading import lambertian_shading
from ssnerf_method.scene.raycast import PinholeCamera, cast_rays, pixel_grid
from ssnerf_method.scene.room import SEMANTIC_CLASSES, SEMANTIC_COLORS, Room, build_room

HFOV_DEG = 75.0
"""Horizontal field of view of the pinhole camera."""

SUPERSAMPLE = 2
"""RGB is averaged over SUPERSAMPLE x SUPERSAMPLE rays per pixel."""

EDGE_THRESHOLDS = (100.0, 200.0)
"""Canny hysteresis thresholds (low, high) on the 8-bit grey RGB image."""

KEYPOINT_SIGMA = 1.5
"""With `--keypoint-label blobs`: standard deviation in pixels of each keypoint's Gaussian blob."""
KEYPOINT_DETECTOR: Detector = "sift"
"""With `--keypoint-label blobs`: OpenCV's SIFT (the scenes' detector before the response map became the default)."""

LABEL_DIRS = ("images", "depth", "semantics", "normals", "shading", "keypoints", "edges")
"""Sub-folders written per frame; `images` holds RGB, the others the label of the same name."""


@dataclass
class MakeSceneConfig:
    """Render the embedded furnished-room scene as a nerfstudio dataset with SS-NeRF property labels."""

    output_dir: tyro.conf.Positional[Path]
    """Folder to write (must be missing or empty unless --overwrite)."""
    width: int = 128
    """Image width in pixels."""
    height: int = 96
    """Image height in pixels."""
    num_frames: int = 60
    """Number of frames along the closed camera loop."""
    seed: int = 0
    """Seed of the camera loop's phase/shape and of the colour jitter (same seed, same bytes)."""
    test_every: int = 5
    """Frame i is a test (and val) frame when i % test_every == test_every // 2."""
    path_frames: int = 120
    """Frames of the fly-through along the same loop written to camera_paths/fly_through.json (for `ns-render
    camera-path` and the viewer's render panel); 0 writes none."""
    path_seconds: float = 5.0
    """Duration of the fly-through video."""
    keypoint_label: KeypointLabel = "response"
    """Keypoint label: SURF's dense blob-response map (default; a field learns it) or `blobs`, SIFT keypoints splatted
    as Gaussians of `KEYPOINT_SIGMA` px (the scenes' label before 2026-12; fields render it empty)."""
    overwrite: bool = False
    """Replace the scene files (transforms.json and the label folders) of a non-empty output_dir."""


@dataclass
class RenderedView:
    """One rendered frame, before quantisation."""

    rgb: np.ndarray
    """(H, W, 3) anti-aliased RGB in [0, 1]."""
    depth: np.ndarray
    """(H, W) z-depth in metres at pixel centres."""
    normals: np.ndarray
    """(H, W, 3) camera-frame unit normals (OpenGL axes) at pixel centres."""
    semantics: np.ndarray
    """(H, W) uint8 class ids at pixel centres."""


def intrinsics(width: int, height: int) -> Dict[str, float]:
    """Pinhole intrinsics with `HFOV_DEG` horizontal field of view, square pixels, centred principal point."""
    focal = width / 2.0 / np.tan(np.deg2rad(HFOV_DEG) / 2.0)
    return {"fl_x": float(focal), "fl_y": float(focal), "cx": width / 2.0, "cy": height / 2.0}


def look_pose(position: np.ndarray, forward: np.ndarray) -> np.ndarray:
    """4x4 camera-to-world matrix (OpenGL: x right, y up, looking along -z) at `position` looking along `forward`."""
    forward = forward / np.linalg.norm(forward)
    right = np.cross(forward, np.array([0.0, 1.0, 0.0]))
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = right, up, -forward, position
    return pose


def camera_path(num_frames: int, seed: int) -> List[np.ndarray]:
    """Camera-to-world poses along a closed elliptical loop around the middle of the room, clear of furniture.

    The camera looks outwards from the loop's centre, swinging left/right and tilting slightly up/down, so the
    frames see every wall and piece of furniture while consecutive frames overlap strongly.
    """
    rng = np.random.default_rng([seed, 1])
    phase = rng.uniform(0.0, 2 * np.pi)
    radius_x, radius_z = np.array([0.9, 0.75]) * rng.uniform(0.9, 1.1, 2)
    wobble = rng.uniform(0.0, 2 * np.pi, 3)
    poses = []
    for i in range(num_frames):
        theta = phase + 2 * np.pi * i / num_frames
        position = np.array(
            [-0.55 + radius_x * np.cos(theta), 1.45 + 0.15 * np.sin(2 * theta + wobble[0]), radius_z * np.sin(theta)]
        )
        yaw = theta + 0.35 * np.sin(3 * theta + wobble[1])
        pitch = -0.1 + 0.15 * np.sin(2 * theta + wobble[2])
        forward = np.array([np.cos(pitch) * np.cos(yaw), np.sin(pitch), np.cos(pitch) * np.sin(yaw)])
        poses.append(look_pose(position, forward))
    return poses


def render_view(room: Room, camera: PinholeCamera) -> RenderedView:
    """Cast the pixel-centre rays and the supersampling rays together, and assemble one frame."""
    h, w, s2 = camera.height, camera.width, SUPERSAMPLE**2
    centre_x, centre_y = pixel_grid(w, h)
    sub_x, sub_y = pixel_grid(w, h, SUPERSAMPLE)
    origin, directions = camera.rays(
        np.concatenate([centre_x.reshape(-1), sub_x.reshape(-1)]),
        np.concatenate([centre_y.reshape(-1), sub_y.reshape(-1)]),
    )
    hits = cast_rays(room.primitives, origin, directions)
    radiance = room.shade(hits)[h * w :]
    rotation = camera.camera_to_world[:3, :3]
    centre = slice(0, h * w)
    return RenderedView(
        rgb=radiance.reshape(h, w, s2, 3).mean(axis=2),
        depth=np.where(np.isfinite(hits.t[centre]), hits.t[centre], 0.0).reshape(h, w),
        normals=(hits.normal[centre] @ rotation).reshape(h, w, 3),
        semantics=hits.semantic[centre].reshape(h, w),
    )


def _to_uint8(values: np.ndarray) -> np.ndarray:
    return np.round(np.clip(values, 0.0, 1.0) * 255.0).astype(np.uint8)


def _prepare_output_dir(output_dir: Path, overwrite: bool) -> None:
    """Refuse a non-empty folder unless `overwrite`; then remove only what a previous run of this tool wrote."""
    if output_dir.exists() and any(output_dir.iterdir()):
        if not overwrite:
            raise FileExistsError(
                f"{output_dir} exists and is not empty; pass --overwrite to replace its scene, or pick another folder."
            )
        (output_dir / "transforms.json").unlink(missing_ok=True)
        for name in LABEL_DIRS:
            shutil.rmtree(output_dir / name, ignore_errors=True)
    for name in LABEL_DIRS:
        (output_dir / name).mkdir(parents=True, exist_ok=True)


def make_scene(config: MakeSceneConfig) -> Path:
    """Render the scene into `config.output_dir` and return the path of its transforms.json."""
    _prepare_output_dir(config.output_dir, config.overwrite)
    room = build_room(config.seed)
    k = intrinsics(config.width, config.height)
    frames = []
    train, test = [], []
    for i, pose in enumerate(camera_path(config.num_frames, config.seed)):
        camera = PinholeCamera(config.width, config.height, k["fl_x"], k["fl_y"], k["cx"], k["cy"], pose)
        view = render_view(room, camera)
        rgb = _to_uint8(view.rgb)
        labels = {
            "depth": np.round(np.clip(view.depth * 1000.0, 0, 65535)).astype(np.uint16),
            "semantics": view.semantics,
            "normals": _to_uint8((view.normals + 1.0) / 2.0),
            "shading": _to_uint8(lambertian_shading(view.normals, k["fl_x"], k["fl_y"], k["cx"], k["cy"])),
            "keypoints": _to_uint8(keypoint_label(rgb, config.keypoint_label, KEYPOINT_SIGMA, KEYPOINT_DETECTOR)),
            "edges": _to_uint8(canny_edges(rgb, *EDGE_THRESHOLDS)),
        }
        name = f"frame_{i:05d}.png"
        frame = {"file_path": f"images/{name}", "transform_matrix": pose.tolist()}
        cv2.imwrite(str(config.output_dir / "images" / name), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
        for label, image in labels.items():
            if image.ndim == 3:
                image = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
            cv2.imwrite(str(config.output_dir / label / name), image)
            frame[f"{label}_file_path"] = f"{label}/{name}"
        frames.append(frame)
        (test if i % config.test_every == config.test_every // 2 else train).append(frame["file_path"])

    transforms = {
        "camera_model": "OPENCV",
        **k,
        "w": config.width,
        "h": config.height,
        "k1": 0.0,
        "k2": 0.0,
        "p1": 0.0,
        "p2": 0.0,
        "semantic_classes": list(SEMANTIC_CLASSES),
        "semantic_colors": [list(color) for color in SEMANTIC_COLORS],
        "train_filenames": train,
        "val_filenames": test,
        "test_filenames": test,
        "ssnerf_scene": {
            "generator": "ssnerf-make-scene",
            "seed": config.seed,
            "num_frames": config.num_frames,
            "test_every": config.test_every,
            "hfov_deg": HFOV_DEG,
            "depth_unit": "millimetre z-depth (distance along the camera's viewing axis)",
            "normals_frame": "camera, OpenGL axes (x right, y up, z towards the viewer), stored as (n + 1) / 2 * 255",
            "shading": "Lambertian, point light at the camera centre: clip(dot(n, -view_dir), 0, 1)",
            "keypoints": describe_keypoint_label(config.keypoint_label, KEYPOINT_SIGMA, KEYPOINT_DETECTOR),
            "edges": f"Canny on the 8-bit grey RGB, thresholds {EDGE_THRESHOLDS[0]:g} / {EDGE_THRESHOLDS[1]:g}",
        },
        "frames": frames,
    }
    path = config.output_dir / "transforms.json"
    path.write_text(json.dumps(transforms, indent=2) + "\n")
    if config.path_frames > 0:
        write_fly_through(config, k["fl_y"])
    return path


FLY_THROUGH = Path("camera_paths") / "fly_through.json"
"""The generated scene's camera path, relative to its folder."""


def write_fly_through(config: MakeSceneConfig, fy: float) -> Path:
    """The camera loop sampled `path_frames` times, in the model's frame (as the dataparser will place the data)."""
    outputs = SSNeRFDataParserConfig(data=config.output_dir).setup().get_dataparser_outputs("train")
    poses = to_model_frame(np.stack(camera_path(config.path_frames, config.seed)), outputs)
    return write_camera_path(config.output_dir / FLY_THROUGH, list(poses), config.width, config.height, fy,
                             config.path_seconds)


def entrypoint() -> None:
    """Console script: parse the CLI, render, and report where the scene went and how long it took."""
    config = tyro.cli(MakeSceneConfig)
    start = time.perf_counter()
    try:
        path = make_scene(config)
    except FileExistsError as err:
        sys.exit(f"ssnerf-make-scene: {err}")
    print(
        f"ssnerf-make-scene: wrote {config.num_frames} frames ({config.width}x{config.height}) to {path.parent} "
        f"in {time.perf_counter() - start:.1f} s"
    )


if __name__ == "__main__":
    entrypoint()
