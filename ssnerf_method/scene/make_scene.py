"""`ssnerf-make-scene OUT_DIR`: render the embedded default SS-NeRF scene as a nerfstudio dataset with property labels.

A camera follows a `loop` (dense, the demo's) or a `walkthrough` (sparse as the paper's Replica scenes) through the
procedural room (`room.py`). Each frame gets supersampled RGB and, at pixel centres, the ray caster's z-depth, classes
and camera-frame normals; the other labels come from `ssnerf_method.label_makers`. Deterministic for a seed.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Literal, Optional

import numpy as np
import tyro

from ssnerf_method.data.camera_path import to_model_frame, write_camera_path
from ssnerf_method.data.classes import SEMANTIC_CLASSES, SEMANTIC_COLORS
from ssnerf_method.data.dataparser import SSNeRFDataParserConfig
from ssnerf_method.importers.writer import DatasetWriter, centred_pinhole
from ssnerf_method.label_makers.encoding import to_uint8
from ssnerf_method.label_makers.makers import FrameSources, LabelOptions
from ssnerf_method.label_makers.shading import camera_ray_directions
from ssnerf_method.properties import labelled_properties
from ssnerf_method.scene.raycast import PinholeCamera, cast_rays, pixel_grid
from ssnerf_method.scene.room import Room, build_room
from ssnerf_method.scene.textures import surface_grain

HFOV_DEG = 75.0
"""Horizontal field of view of the pinhole camera."""

SUPERSAMPLE = 2
"""RGB is averaged over SUPERSAMPLE x SUPERSAMPLE rays per pixel."""

Trajectory = Literal["loop", "walkthrough"]
NormalsLabel = Literal["exact", "from-depth"]

SPLITS: Dict[str, Dict[str, int]] = {
    "loop": {"num_frames": 60, "test_every": 5, "test_offset": 2},
    "walkthrough": {"num_frames": 50, "test_every": 8, "test_offset": 0},
}
"""Each trajectory's default frame count and test frames (i % test_every == test_offset; walkthrough: llffhold)."""

LABEL_DIRS = ("images", "depth", *(spec.name for spec in labelled_properties()))
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
    num_frames: Optional[int] = None
    """Number of frames along the trajectory (default: 60 for the loop, 50 for the walkthrough)."""
    seed: int = 0
    """Seed of the trajectory's shape and of the colour jitter (same seed, same bytes)."""
    test_every: Optional[int] = None
    """Frame i is a test (and val) frame when i % test_every == test_offset (default: loop 5, walkthrough 8)."""
    path_frames: int = 120
    """Frames of the fly-through written to camera_paths/fly_through.json (for `ns-render camera-path`); 0: none."""
    path_seconds: float = 5.0
    """Duration of the fly-through video."""
    overwrite: bool = False
    """Replace the scene files (transforms.json and the label folders) of a non-empty output_dir."""
    trajectory: Trajectory = "loop"
    """`loop`: a small closed loop in the middle of the room, looking outwards (dense; the demo's). `walkthrough`: a
    long walk across the room past the furniture, as sparse along the path as the paper's scenes (the benchmark's)."""
    normals: NormalsLabel = "exact"
    """Normal label: the ray caster's exact normals, or derived from the written depth map by finite differences as
    the paper derived them (`from-depth`; pixels at depth discontinuities are left unlabelled)."""
    test_offset: Optional[int] = None
    """First test frame (default: 2 for the loop, 0 for the walkthrough, the authors' split)."""
    grain: float = 0.0
    """Strength of a fine surface texture (0: none, the default scene; 0.3: photo-like detail) that makes the
    renders posable by structure from motion, as a phone capture of the room would be (`ssnerf-process`'s tests)."""

    def __post_init__(self) -> None:
        defaults = SPLITS[self.trajectory]
        self.num_frames = self.num_frames if self.num_frames is not None else defaults["num_frames"]
        if self.test_every is None:
            self.test_every = defaults["test_every"]
            self.test_offset = defaults["test_offset"] if self.test_offset is None else self.test_offset
        elif self.test_offset is None:
            self.test_offset = self.test_every // 2 if self.trajectory == "loop" else 0

    def is_test(self, frame: int) -> bool:
        """Whether frame `frame` is held out (a test and val frame)."""
        return frame % self.test_every == self.test_offset  # type: ignore[operator]


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


WALKTHROUGH_WAYPOINTS = np.array([
    (2.5, 1.5), (2.4, 0.0), (1.6, -0.9), (0.5, -1.6), (-0.8, -1.9), (-2.0, -1.3), (-2.3, 0.0), (-1.9, 1.4),
    (-0.7, 1.9), (0.6, 1.6), (1.3, 0.6), (0.4, -0.3), (-0.8, 0.3),
])
"""(x, z) in metres of the walk past the furniture, clear of anything above its 1.15 m minimum height."""


def camera_path(trajectory: Trajectory, num_frames: int, seed: int) -> List[np.ndarray]:
    """Camera-to-world poses of `num_frames` frames along `trajectory` (see `loop_path`, `walkthrough_path`)."""
    return (loop_path if trajectory == "loop" else walkthrough_path)(num_frames, seed)


def walkthrough_path(num_frames: int, seed: int) -> List[np.ndarray]:
    """Camera-to-world poses evenly spaced along a Catmull-Rom spline through `WALKTHROUGH_WAYPOINTS` (jittered per
    seed), heading where it walks with swinging yaw, pitch and height: frames far apart, with occlusions."""
    rng = np.random.default_rng([seed, 2])
    points = WALKTHROUGH_WAYPOINTS + np.clip(rng.normal(0.0, 0.06, WALKTHROUGH_WAYPOINTS.shape), -0.1, 0.1)
    padded = np.concatenate([2 * points[:1] - points[1:2], points, 2 * points[-1:] - points[-2:-1]])
    samples = []
    for i in range(len(points) - 1):  # uniform Catmull-Rom, densely sampled per segment
        p0, p1, p2, p3 = padded[i : i + 4]
        t = np.linspace(0.0, 1.0, 200, endpoint=False)[:, None]
        samples.append(0.5 * (2 * p1 + (p2 - p0) * t + (2 * p0 - 5 * p1 + 4 * p2 - p3) * t**2
                              + (3 * p1 - p0 - 3 * p2 + p3) * t**3))
    curve = np.concatenate([*samples, points[-1:]])
    length = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(curve, axis=0), axis=1))])
    at = np.linspace(0.0, length[-1], num_frames)
    phase = rng.uniform(0.0, 2 * np.pi, 3)
    poses = []
    for s in at:
        x, z = np.interp(s, length, curve[:, 0]), np.interp(s, length, curve[:, 1])
        ahead = min(s + 0.05, length[-1])
        dx = np.interp(ahead, length, curve[:, 0]) - np.interp(ahead - 0.05, length, curve[:, 0])
        dz = np.interp(ahead, length, curve[:, 1]) - np.interp(ahead - 0.05, length, curve[:, 1])
        u = s / length[-1]
        yaw = np.arctan2(dz, dx) + 0.7 * np.sin(2 * np.pi * 5 * u + phase[0])
        pitch = -0.18 + 0.25 * np.sin(2 * np.pi * 3 * u + phase[1])
        height = 1.45 + 0.25 * np.sin(2 * np.pi * 4 * u + phase[2])
        forward = np.array([np.cos(pitch) * np.cos(yaw), np.sin(pitch), np.cos(pitch) * np.sin(yaw)])
        poses.append(look_pose(np.array([x, height, z]), forward))
    return poses


def loop_path(num_frames: int, seed: int) -> List[np.ndarray]:
    """Camera-to-world poses on a closed loop mid-room, looking outwards: every wall seen, frames overlapping."""
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


def render_view(room: Room, camera: PinholeCamera, grain: float = 0.0) -> RenderedView:
    """Cast the pixel-centre rays and the supersampling rays together, and assemble one frame (albedo times
    `surface_grain` when `grain` > 0)."""
    h, w, s2 = camera.height, camera.width, SUPERSAMPLE**2
    centre_x, centre_y = pixel_grid(w, h)
    sub_x, sub_y = pixel_grid(w, h, SUPERSAMPLE)
    origin, directions = camera.rays(
        np.concatenate([centre_x.reshape(-1), sub_x.reshape(-1)]),
        np.concatenate([centre_y.reshape(-1), sub_y.reshape(-1)]),
    )
    hits = cast_rays(room.primitives, origin, directions)
    if grain > 0:
        hits.albedo = np.clip(hits.albedo * surface_grain(hits.position, grain)[:, None], 0.0, 1.0)
    radiance = room.shade(hits)[h * w :]
    rotation = camera.camera_to_world[:3, :3]
    centre = slice(0, h * w)
    return RenderedView(
        rgb=radiance.reshape(h, w, s2, 3).mean(axis=2),
        depth=np.where(np.isfinite(hits.t[centre]), hits.t[centre], 0.0).reshape(h, w),
        normals=(hits.normal[centre] @ rotation).reshape(h, w, 3),
        semantics=hits.semantic[centre].reshape(h, w),
    )


def label_options(config: MakeSceneConfig) -> LabelOptions:
    """The label makers' defaults (`ssnerf-label`'s), with the normal label from exact normals or written depth."""
    return LabelOptions(
        normals_source="exact" if config.normals == "exact" else "depth", semantics_from="the ray caster's class ids",
    )


def view_sources(view: RenderedView, rgb: np.ndarray, depth: np.ndarray, rays: np.ndarray) -> FrameSources:
    """What the label makers read of a rendered frame: written RGB and mm depth, rays, true normals, class ids."""
    return FrameSources(rgb=rgb, rays=lambda scale: rays, depth=lambda: depth.astype(np.float64),
                        normals=view.normals, semantics=lambda: view.semantics)


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
    options = label_options(config)
    rays = camera_ray_directions(config.height, config.width, k["fl_x"], k["fl_y"], k["cx"], k["cy"])  # one camera
    writer = DatasetWriter(config.output_dir)
    train, test = [], []
    for i, pose in enumerate(camera_path(config.trajectory, config.num_frames, config.seed)):
        camera = PinholeCamera(config.width, config.height, k["fl_x"], k["fl_y"], k["cx"], k["cy"], pose)
        view = render_view(room, camera, config.grain)
        rgb = to_uint8(view.rgb)
        depth = np.round(np.clip(view.depth * 1000.0, 0, 65535)).astype(np.uint16)
        sources = view_sources(view, rgb, depth, rays)
        labels = {"depth": depth, **{spec.name: spec.label_maker.make(sources, options)
                                     for spec in labelled_properties()}}
        file_path = writer.add_frame(i, rgb, pose, labels)
        (test if config.is_test(i) else train).append(file_path)

    provenance = {
        "generator": "ssnerf-make-scene",
        "seed": config.seed,
        "trajectory": config.trajectory,
        "num_frames": config.num_frames,
        "test_every": config.test_every,
        "test_offset": config.test_offset,
        "hfov_deg": HFOV_DEG,
        **({"grain": config.grain} if config.grain > 0 else {}),
        "depth_unit": "millimetre z-depth (distance along the camera's viewing axis)",
        **{spec.name: spec.label_maker.describe(options) for spec in labelled_properties()},
    }
    path = writer.write_transforms(
        centred_pinhole(k["fl_x"], config.width, config.height),
        {"train": train, "val": test, "test": test}, provenance, SEMANTIC_CLASSES, SEMANTIC_COLORS, "ssnerf_scene",
    )
    if config.path_frames > 0:
        write_fly_through(config, k["fl_y"])
    return path


FLY_THROUGH = Path("camera_paths") / "fly_through.json"
"""The generated scene's camera path, relative to its folder."""


def write_fly_through(config: MakeSceneConfig, fy: float) -> Path:
    """The camera loop sampled `path_frames` times, in the model's frame (as the dataparser will place the data)."""
    outputs = SSNeRFDataParserConfig(data=config.output_dir).setup().get_dataparser_outputs("train")
    poses = to_model_frame(np.stack(camera_path(config.trajectory, config.path_frames, config.seed)), outputs)
    return write_camera_path(config.output_dir / FLY_THROUGH, list(poses), config.width, config.height, fy,
                             config.path_seconds)
