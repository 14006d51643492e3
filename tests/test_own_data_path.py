"""The README's "Quick start on your own data" block, run as written on a generated photo capture.

The capture is the embedded room rendered with surface grain as 36 JPEG photos and nothing else (no poses, no depth,
no labels). The block's commands are read from README.md and run in order in a fresh folder holding `my_photos/`,
with only what makes them short appended (`SHORTER`: fewer steps, no viewer) and `TIMESTAMP` named; the
viewer, which serves until stopped, is left out. Every command must exit 0 without a traceback; then the poses it
recovered must match the true ones, the evaluation must score normals (which came from the depth model ssnerf-label
trained, the capture having no depth), and the export must hold the labelled points.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Dict, List

import numpy as np

from ssnerf_method.evaluation.poses import pose_errors, poses_by_photo_order

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
SECTION = "## Quick start on your own data"
SERVERS = {"ns-viewer"}
"""Commands that serve until stopped: checked by scripts/check_environment.py (--help), not run here."""
SHORTER: Dict[str, List[str]] = {
    "ssnerf-label": ["--depth-model-steps", "50"],
    "ns-train": ["--max-num-iterations", "60", "--vis", "tensorboard", "--machine.device-type", "cpu",
                 "--timestamp", "run", "--pipeline.datamanager.train-num-rays-per-batch", "512",
                 "--pipeline.datamanager.dataparser.downscale-factor", "2"],
    "ssnerf-export-points": ["--num-points", "20000"],
    "ns-render": ["--downscale-factor", "4", "--interpolation-steps", "1", "--frame-rate", "4"],
}
"""Flags appended per program so that the block runs in a few minutes on 2 CPU cores."""


def own_data_commands(readme: Path) -> List[str]:
    """The block's command lines, continuations joined, comments and `source` dropped."""
    text = readme.read_text()
    section = text[text.index(SECTION):]
    block = re.search(r"```bash\n(.*?)```", section, re.S).group(1)  # type: ignore[union-attr]
    lines = []
    for line in block.replace("\\\n", " ").splitlines():
        words = shlex.split(line, comments=True)
        if words and words[0] != "source":
            lines.append(words)
    return [shlex.join(words) for words in lines]


def test_the_readme_own_data_block_runs_on_photos_alone(photo_capture: Path, tmp_path: Path) -> None:
    capture = photo_capture
    work = tmp_path / "work"
    work.mkdir()
    shutil.copytree(capture, work / "my_photos")
    commands = own_data_commands(ROOT / "README.md")
    programs = [shlex.split(command)[0] for command in commands]
    assert programs[:2] == ["ssnerf-process", "ssnerf-label"] and "ns-train" in programs, programs
    env = {**os.environ, "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS", "2"),
           "PATH": f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}"}
    for command in commands:
        words = shlex.split(command.replace("TIMESTAMP", "run"))
        if words[0] in SERVERS:
            continue
        words += SHORTER.get(words[0], [])
        start = time.perf_counter()
        done = subprocess.run(words, cwd=work, env=env, capture_output=True, text=True, timeout=900)
        print(f"{time.perf_counter() - start:6.1f} s  {shlex.join(words)}")
        output = done.stdout + done.stderr
        assert done.returncode == 0 and "Traceback" not in output, f"{shlex.join(words)}\n{output[-4000:]}"

    errors = pose_errors(*poses_by_photo_order(capture.parent / "scene" / "transforms.json",
                                              work / "my_scene" / "transforms.json"))
    rotation, translation = float(np.median(errors.rotation_deg)), float(np.median(errors.translation))
    print(f"pose errors: median rotation {rotation:.3f} deg, median translation {100 * translation:.2f}% of "
          f"{errors.scene_size:.2f} m")
    assert rotation <= 2.0 and translation <= 0.05

    frames = json.loads((work / "my_scene" / "transforms.json").read_text())["frames"]
    assert all("normals_file_path" in frame and "depth_file_path" not in frame for frame in frames)
    metrics = json.loads((work / "eval.json").read_text())["results"]
    assert any(key.startswith("normals_") for key in metrics) and metrics["psnr"] > 10, metrics
    assert (work / "my_points" / "points.ply").stat().st_size > 1000
    assert (work / "fly.mp4").stat().st_size > 0
