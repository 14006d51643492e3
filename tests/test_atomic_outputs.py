"""Results are whole or absent: `atomic_file` never leaves a half-written file under its final name, and a benchmark
killed while writing a run's metrics rescores that run when the same command runs again."""

from __future__ import annotations

import json
import os
import socket
import stat
from pathlib import Path

import pytest
import torch

from ssnerf_method.atomic import PARTIAL_SUFFIX, atomic_file, write_text_atomic
from ssnerf_method.experiments import benchmark
from ssnerf_method.experiments.benchmark import NERF, BenchmarkConfig, SceneBenchmark, quick_config
from ssnerf_method.scene.make_scene import MakeSceneConfig, make_scene


class Killed(BaseException):
    """A kill, simulated in this process: raised mid-write, caught by nothing in the code under test."""


def test_a_write_that_dies_midway_leaves_the_old_file(tmp_path: Path) -> None:
    path = tmp_path / "metrics.json"
    write_text_atomic(path, '{"psnr": 20.0}')
    with pytest.raises(Killed):
        with atomic_file(path) as stream:
            stream.write('{"psnr": 3')
            stream.flush()
            raise Killed
    assert path.read_text() == '{"psnr": 20.0}'
    assert [child.name for child in tmp_path.iterdir()] == ["metrics.json"]  # and no temporary file left


def test_a_written_file_has_the_permissions_of_any_new_file(tmp_path: Path) -> None:
    previous = os.umask(0o022)
    try:
        write_text_atomic(tmp_path / "new" / "report.md", "# report\n")
    finally:
        os.umask(previous)
    assert stat.S_IMODE((tmp_path / "new" / "report.md").stat().st_mode) == 0o644


def test_a_benchmark_killed_while_writing_a_runs_metrics_rescores_that_run(tmp_path: Path, monkeypatch) -> None:
    """The metrics write dies halfway: no metrics.json is left, and the same call again scores the run from its
    final checkpoint (not retrained), ignoring what the dead write left beside it."""
    torch.set_num_threads(1)
    scene = tmp_path / "scene"
    make_scene(MakeSceneConfig(output_dir=scene, width=40, height=30, num_frames=10, path_frames=0))  # type: ignore
    config = quick_config(BenchmarkConfig(scenes=(scene,), output=tmp_path / "bench", properties=(),
                                          all_properties_model=False, steps=4))
    bench = SceneBenchmark(config, scene, "scene")
    [nerf] = bench.models()
    result = bench.run_dir(NERF) / "metrics.json"

    trainings = []
    train = benchmark.train_in_process
    monkeypatch.setattr(benchmark, "train_in_process", lambda trainer: (trainings.append(trainer), train(trainer)))
    written = {}

    def killed_mid_write(path: Path, text: str) -> None:
        written["text"] = text
        with atomic_file(path) as stream:
            stream.write(text[: len(text) // 2])
            stream.flush()
            raise Killed

    monkeypatch.setattr(benchmark, "write_text_atomic", killed_mid_write)
    with pytest.raises(Killed):
        bench.train_and_score(nerf)
    assert len(trainings) == 1 and bench.checkpoint(NERF).is_file() and not result.exists()
    # what a SIGKILL (unlike this exception) leaves: the dead writer's half-written temporary file
    leftover = result.with_name(f".metrics.json.{socket.gethostname().replace('.', '_')}-999999999.0a1b2c3d"
                                f"{PARTIAL_SUFFIX}")
    leftover.write_text(written["text"][: len(written["text"]) // 2])

    monkeypatch.undo()
    monkeypatch.setattr(benchmark, "train_in_process", lambda trainer: (trainings.append(trainer), train(trainer)))
    metrics = bench.train_and_score(nerf)  # the same command, run again
    assert len(trainings) == 1  # rescored from the final checkpoint, not retrained
    saved, first = json.loads(result.read_text()), json.loads(written["text"])
    assert {"psnr", "ssim"} <= set(saved) and saved["psnr"] == metrics["psnr"] == first["psnr"]
