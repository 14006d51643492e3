"""Shared fixtures: a tiny dataset in the SS-NeRF format, written from arrays so each test can break one file; and a
tiny generated scene with a briefly trained `ssnerf-lite` on it (for rendering and export tests)."""

from __future__ import annotations

import copy
import json
import sys
from pathlib import Path
from typing import Callable, Dict, List, Optional, Tuple

import numpy as np
import pytest
import torch
from PIL import Image

from ssnerf_method.properties import REGISTRY, PropertySpec, RenderContext

CLASSES = ["void", "wall", "floor", "table"]
WIDTH, HEIGHT = 16, 12


def look_at(position: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Camera-to-world (OpenGL: x right, y up, looking along -z) at `position` looking at `target`."""
    forward = target - position
    forward = forward / np.linalg.norm(forward)
    right = np.cross(forward, np.array([0.0, 0.0, 1.0]))
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, up, -forward, position
    return c2w


def random_label(spec: PropertySpec, rng: np.random.Generator, num_classes: int) -> np.ndarray:
    """A random label of `spec` in its file encoding: its kind's rendering of random per-sample outputs (whatever a
    field renders is a valid label), so a new property's fixture needs nothing here."""
    raw = torch.from_numpy(rng.normal(size=(HEIGHT * WIDTH, 1, spec.kind.head_channels(num_classes)))).float()
    prediction = spec.kind.render(spec.kind.activation(raw), torch.ones(HEIGHT * WIDTH, 1, 1), RenderContext())
    return spec.kind.encode(prediction.reshape(HEIGHT, WIDTH, -1))


def write_tiny_dataset(root: Path, num_frames: int = 6, seed: int = 0) -> Dict:
    """Write `num_frames` random 16x12 frames with every registry property (`random_label`, in `<name>/`) and a
    depth map; returns the transforms dict."""
    rng = np.random.default_rng(seed)
    labelled = [spec for spec in REGISTRY.values() if spec.file_key is not None]
    for folder in ("images", "depth", *(spec.name for spec in labelled)):
        (root / folder).mkdir(parents=True, exist_ok=True)
    frames = []
    for index in range(num_frames):
        name = f"frame_{index:03d}.png"
        angle = 2 * np.pi * index / num_frames
        c2w = look_at(np.array([np.cos(angle), np.sin(angle), 0.2]), np.zeros(3))
        Image.fromarray(rng.integers(0, 255, (HEIGHT, WIDTH, 3), dtype=np.uint8)).save(root / "images" / name)
        Image.fromarray(np.full((HEIGHT, WIDTH), 1500, dtype=np.uint16)).save(root / "depth" / name)
        frame = {"file_path": f"images/{name}", "transform_matrix": c2w.tolist(), "depth_file_path": f"depth/{name}"}
        for spec in labelled:
            Image.fromarray(random_label(spec, rng, len(CLASSES))).save(root / spec.name / name)
            frame[spec.file_key] = f"{spec.name}/{name}"
        frames.append(frame)
    transforms = {
        "camera_model": "OPENCV",
        "fl_x": 14.0, "fl_y": 14.0, "cx": WIDTH / 2, "cy": HEIGHT / 2, "w": WIDTH, "h": HEIGHT,
        "semantic_classes": CLASSES,
        "train_filenames": [frame["file_path"] for frame in frames[1:]],
        "val_filenames": [frames[0]["file_path"]],
        "test_filenames": [frames[0]["file_path"]],
        "frames": frames,
    }
    (root / "transforms.json").write_text(json.dumps(transforms, indent=2))
    return transforms


def one_line_error(err: str, program: str, words) -> str:
    """The one line a console script printed for bad input (no traceback), holding every one of `words`."""
    assert "Traceback" not in err
    lines = [line for line in err.splitlines() if line.startswith(f"{program}: ")]
    assert len(lines) == 1, lines
    assert all(word in lines[0] for word in words), (lines[0], words)
    return lines[0]


def snapshot(root: Path) -> Dict[str, Optional[bytes]]:
    """Every path below `root` with its bytes (None for a folder): equal before and after means nothing was written."""
    return {str(path.relative_to(root)): path.read_bytes() if path.is_file() else None
            for path in sorted(root.rglob("*"))}


def ssnerf_label_refuses(data: Path, arguments: List[str], words, err_reader, monkeypatch) -> None:
    """`ssnerf-label DATA ARGUMENTS` (in this process) exits 1 with one line holding `words`, and writes nothing.
    `err_reader`: pytest's `capsys`."""
    from ssnerf_method.cli import label

    before = snapshot(data)
    monkeypatch.setattr(sys, "argv", ["ssnerf-label", str(data), "--workers", "1", *arguments])
    with pytest.raises(SystemExit) as exit_info:
        label.entrypoint()
    assert exit_info.value.code == 1
    one_line_error(err_reader.readouterr().err, "ssnerf-label", words)
    assert snapshot(data) == before


@pytest.fixture
def tiny_dataset(tmp_path: Path) -> Path:
    root = tmp_path / "tiny"
    write_tiny_dataset(root)
    return root


@pytest.fixture
def edit_transforms() -> Callable[[Path, Callable[[Dict], None]], None]:
    """Apply an in-place edit to a dataset's transforms.json."""

    def edit(root: Path, change: Callable[[Dict], None]) -> None:
        path = root / "transforms.json"
        transforms = json.loads(path.read_text())
        change(transforms)
        path.write_text(json.dumps(transforms))

    return edit


@pytest.fixture(scope="session")
def trained_scene(tmp_path_factory) -> Tuple[Path, Path]:
    """A generated 40x30 scene (10 frames, a 12-frame fly-through) and the config.yml of an `ssnerf-lite` with
    every property trained on it for 150 steps at the benchmark's --quick sizes (one thread)."""
    import torch

    from ssnerf_method.engine.trainer import train_in_process
    from ssnerf_method.experiments.benchmark import shrink_for_quick
    from ssnerf_method.method_configs import ssnerf_lite_config
    from ssnerf_method.scene.make_scene import MakeSceneConfig, make_scene

    torch.set_num_threads(1)
    torch.manual_seed(0)
    root = tmp_path_factory.mktemp("trained_scene")
    scene = root / "scene"
    make_scene(MakeSceneConfig(output_dir=scene, width=40, height=30, num_frames=10, path_frames=12, path_seconds=1.0))
    config = copy.deepcopy(ssnerf_lite_config)
    config.pipeline.datamanager.data = scene  # type: ignore[attr-defined]
    shrink_for_quick(config)
    config.machine.device_type = "cpu"
    config.vis = "tensorboard"
    config.output_dir, config.experiment_name, config.timestamp = root / "outputs", "tiny", "run"
    config.max_num_iterations = config.steps_per_save = 150
    config.steps_per_eval_batch = config.steps_per_eval_image = config.steps_per_eval_all_images = 10**6
    config.logging.local_writer.enable = False
    train_in_process(config)
    return scene, root / "outputs" / "tiny" / "ssnerf-lite" / "run" / "config.yml"


def write_photo_capture(root: Path, width: int = 256, height: int = 192, num_frames: int = 36) -> Path:
    """The room's loop rendered with surface grain, as `root/photos/*.jpg` (no poses); the scene (with its true
    poses) stays in `root/scene`. 36 frames, 10 degrees apart: 24 (15 degrees) overlap too little to pose."""
    from ssnerf_method.scene.make_scene import MakeSceneConfig, make_scene

    make_scene(MakeSceneConfig(output_dir=root / "scene", width=width, height=height, num_frames=num_frames,
                               grain=0.3, path_frames=0))
    photos = root / "photos"
    photos.mkdir()
    for image in sorted((root / "scene" / "images").iterdir()):
        Image.open(image).convert("RGB").save(photos / f"{image.stem}.jpg", quality=92)
    return photos


@pytest.fixture(scope="session")
def photo_capture(tmp_path_factory) -> Path:
    """`write_photo_capture`'s 36 photos (256x192), made once for ssnerf-process's tests and the README path's."""
    return write_photo_capture(tmp_path_factory.mktemp("photo_capture"))
