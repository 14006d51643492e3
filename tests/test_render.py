"""Property videos with nerfstudio's own `ns-render`: the generated scene's fly-through path lines up with its
cameras, and `ns-render camera-path` writes every property, colour-mapped as the viewer shows it."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import mediapy
import numpy as np
import pytest
import torch

from nerfstudio.cameras.camera_paths import get_path_from_json
from nerfstudio.utils.eval_utils import eval_setup

from ssnerf_method.data.dataparser import SSNeRFDataParserConfig
from ssnerf_method.properties import REGISTRY
from ssnerf_method.scene.make_scene import FLY_THROUGH

NAMES = tuple(REGISTRY)


def test_fly_through_starts_at_the_first_camera(trained_scene) -> None:
    """The path is in the model's frame: its first pose is frame 0's pose after the dataparser's transform."""
    scene, _ = trained_scene
    path = json.loads((scene / FLY_THROUGH).read_text())
    assert len(path["camera_path"]) == 12 and path["seconds"] == 1.0
    cameras = get_path_from_json(path)
    train = SSNeRFDataParserConfig(data=scene).setup().get_dataparser_outputs("train").cameras
    assert torch.allclose(cameras.camera_to_worlds[0], train.camera_to_worlds[0], atol=1e-5)
    assert float(cameras.fy[0]) == pytest.approx(float(train.fy[0]), abs=1e-3)  # the same field of view
    assert (int(cameras.width[0]), int(cameras.height[0])) == (40, 30)
    steps = torch.linalg.norm(cameras.camera_to_worlds[1:, :, 3] - cameras.camera_to_worlds[:-1, :, 3], dim=-1)
    assert steps.max() < 3 * steps.min()  # evenly paced along the loop


def test_ns_render_writes_every_property_as_the_viewer_shows_it(trained_scene, tmp_path: Path) -> None:
    assert shutil.which("ffmpeg"), "ns-render writes videos with ffmpeg: install Debian's `ffmpeg` (make test does)"
    scene, config = trained_scene
    video = tmp_path / "fly_through.mp4"
    command = [
        str(Path(sys.executable).parent / "ns-render"), "camera-path", "--load-config", str(config),
        "--camera-path-filename", str(scene / FLY_THROUGH), "--rendered-output-names", *NAMES,
        "--output-path", str(video),
    ]
    result = subprocess.run(command, capture_output=True, text=True, env={**os.environ, "OMP_NUM_THREADS": "1"},
                            timeout=300)
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-2000:]
    frames = mediapy.read_video(video)
    assert frames.shape == (12, 30, 40 * len(NAMES), 3)  # one 40x30 panel per property, side by side

    _, pipeline, _, _ = eval_setup(config, test_mode="inference")
    cameras = get_path_from_json(json.loads((scene / FLY_THROUGH).read_text()))
    shown = pipeline.model.get_outputs_for_camera(cameras[0:1])
    panels = np.split(frames[0].astype(np.float32) / 255.0, len(NAMES), axis=1)
    for index, name in enumerate(NAMES):
        expected = shown[name].cpu().numpy()
        errors = [np.abs(panel - expected).mean() for panel in panels]
        assert errors[index] < 0.06, (name, errors)  # video compression only
        assert errors[index] == min(errors), (name, errors)
