"""Nothing lost when training is killed: a real `ns-train` killed (SIGKILL) in the middle of writing a checkpoint
leaves only whole checkpoints, `--load-dir` resumes from the last one and `ns-eval` loads it; a truncated newest
checkpoint is skipped, in one line, by `ns-eval`, `ns-render` and `ns-train --load-dir`; a dataset that has moved is
reported with a fix the command in use accepts. Three real commands (about 20 s each to start on 2 cores); the rest
runs nerfstudio's entry points in this process."""

from __future__ import annotations

import dataclasses
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
from copy import deepcopy
from pathlib import Path
from types import SimpleNamespace
from typing import Dict, List

import pytest
import torch
import yaml

from nerfstudio.scripts.eval import ComputePSNR
from nerfstudio.utils.eval_utils import eval_setup

from ssnerf_method.atomic import PARTIAL_SUFFIX
from ssnerf_method.data.validate import validate_dataset
from ssnerf_method.engine.checkpoints import last_good_checkpoint, read_checkpoint, saved_checkpoints
from ssnerf_method.engine.trainer import SSNeRFTrainer, SSNeRFTrainerConfig
from ssnerf_method.errors import UserError
from ssnerf_method.experiments.benchmark import shrink_for_quick
from ssnerf_method.method_configs import ssnerf_lite_config
from ssnerf_method.scene.make_scene import MakeSceneConfig, make_scene

BIN = Path(sys.executable).parent
KILL_STEP = 9
"""The killed run saves every 3 steps: steps 3 and 6 are written whole, the kill comes while step 9 is written."""

KILLED_SAVE = """
import io, os, sys, time
from pathlib import Path

import torch

signal_file, kill_step = Path(sys.argv[1]), int(sys.argv[2])
save = torch.save


def slow_save(state, destination, *args, **kwargs):
    '''Write the first half of `kill_step`'s checkpoint, tell the test, and wait to be killed.'''
    if not (isinstance(state, dict) and state.get("step") == kill_step):
        return save(state, destination, *args, **kwargs)
    buffer = io.BytesIO()
    save(state, buffer, *args, **kwargs)
    stream = open(destination, "wb") if isinstance(destination, (str, os.PathLike)) else destination
    stream.write(buffer.getvalue()[: buffer.tell() // 2])
    stream.flush()
    signal_file.write_text("inside the save")
    time.sleep(600)


torch.save = slow_save
sys.argv = ["ns-train", *sys.argv[3:]]
from nerfstudio.scripts.train import entrypoint

entrypoint()
"""
"""Runs `ns-train` with `torch.save` slowed down mid-write at one step (arguments: signal file, step, ns-train's)."""


def quick_flags() -> List[str]:
    """`shrink_for_quick`'s sizes as ns-train flags: every datamanager and model field it changes."""
    quick = deepcopy(ssnerf_lite_config)
    shrink_for_quick(quick)
    flags = []
    for part in ("datamanager", "model"):
        default, small = getattr(ssnerf_lite_config.pipeline, part), getattr(quick.pipeline, part)
        for field in dataclasses.fields(small):
            value = getattr(small, field.name)
            if value != getattr(default, field.name):
                values = value if isinstance(value, tuple) else (value,)
                flags += [f"--pipeline.{part}.{field.name.replace('_', '-')}", *map(str, values)]
    return flags


def train_arguments(scene: Path, output: Path, timestamp: str, *extra: str) -> List[str]:
    return ["ssnerf-lite", "--data", str(scene), "--output-dir", str(output), "--experiment-name", "run",
            "--timestamp", timestamp, "--vis", "tensorboard", "--machine.device-type", "cpu",
            "--logging.local-writer.enable", "False", *quick_flags(), *extra]


def run_dir(output: Path, timestamp: str) -> Path:
    return output / "run" / "ssnerf-lite" / timestamp


def command_env() -> Dict[str, str]:
    return {**os.environ, "OMP_NUM_THREADS": "1"}


@pytest.fixture(scope="module")
def killed_run(tmp_path_factory) -> SimpleNamespace:
    """A 40x30 generated scene and an `ns-train` (quick sizes) SIGKILLed while writing step 9's checkpoint; what
    its checkpoint folder held right after the kill is in `listing`."""
    root = tmp_path_factory.mktemp("killed_run")
    scene = root / "scene"
    make_scene(MakeSceneConfig(output_dir=scene, width=40, height=30, num_frames=10, path_frames=0))  # type: ignore
    wrapper, signal_file, log = root / "killed_save.py", root / "inside_save", root / "ns-train.log"
    wrapper.write_text(KILLED_SAVE)
    output = root / "outputs"
    arguments = train_arguments(scene, output, "killed", "--max-num-iterations", "12", "--steps-per-save", "3",
                                "--save-only-latest-checkpoint", "False")
    with log.open("w") as stream:
        process = subprocess.Popen([sys.executable, str(wrapper), str(signal_file), str(KILL_STEP), *arguments],
                                   stdout=stream, stderr=subprocess.STDOUT, env=command_env(), start_new_session=True)
    try:
        deadline = time.time() + 400
        while not signal_file.exists():
            assert process.poll() is None, f"ns-train ended before the save: {log.read_text()[-3000:]}"
            assert time.time() < deadline, f"ns-train never reached step {KILL_STEP}'s save"
            time.sleep(0.2)
    finally:
        os.killpg(process.pid, signal.SIGKILL)  # its own session: ns-train and any worker it started
        process.wait()
    folder = run_dir(output, "killed") / "nerfstudio_models"
    return SimpleNamespace(scene=scene, output=output, folder=folder, config=run_dir(output, "killed") / "config.yml",
                           listing=sorted(path.name for path in folder.iterdir()))


def test_a_kill_during_a_save_leaves_only_whole_checkpoints(killed_run) -> None:
    checkpoints = [name for name in killed_run.listing if name.endswith(".ckpt")]
    assert checkpoints == ["step-000000003.ckpt", "step-000000006.ckpt"]
    assert [read_checkpoint(killed_run.folder / name)["step"] for name in checkpoints] == [3, 6]
    partial = [name for name in killed_run.listing if name not in checkpoints]
    assert len(partial) == 1 and partial[0].startswith(".step-000000009.ckpt.") and partial[0].endswith(PARTIAL_SUFFIX)


def test_resume_and_eval_after_the_kill(killed_run, tmp_path: Path, monkeypatch) -> None:
    """`ns-eval` loads step 6; `ns-train --load-dir` continues at step 7 and clears the killed save's leftover."""
    from nerfstudio.scripts.train import entrypoint as ns_train

    torch.set_num_threads(1)
    ComputePSNR(load_config=killed_run.config, output_path=tmp_path / "eval.json").main()
    evaluated = json.loads((tmp_path / "eval.json").read_text())
    assert Path(evaluated["checkpoint"]).name == "step-000000006.ckpt" and "psnr" in evaluated["results"]

    monkeypatch.setattr(sys, "argv", ["ns-train", *train_arguments(
        killed_run.scene, tmp_path, "resumed", "--max-num-iterations", "2", "--load-dir", str(killed_run.folder))])
    ns_train()
    resumed = run_dir(tmp_path, "resumed") / "nerfstudio_models"
    assert [path.name for path in saved_checkpoints(resumed)] == ["step-000000008.ckpt"]  # trained steps 7 and 8
    assert not list(killed_run.folder.glob(f"*{PARTIAL_SUFFIX}"))  # its writer is dead: removed on load


def test_a_truncated_newest_checkpoint_is_skipped_in_one_line(killed_run, tmp_path: Path, capfd, monkeypatch) -> None:
    """On a copy of the killed run with step 6 truncated to 100 kB, `ns-eval` (a real command), `ns-render dataset`
    and `ns-train --load-dir` (their entry points, in this process) each say so in one line and use step 3; no
    traceback."""
    from nerfstudio.scripts.render import DatasetRender
    from nerfstudio.scripts.train import entrypoint as ns_train

    torch.set_num_threads(1)
    run = run_dir(tmp_path / "outputs", "killed")
    shutil.copytree(killed_run.folder, run / "nerfstudio_models", ignore=shutil.ignore_patterns(f"*{PARTIAL_SUFFIX}"))
    config = yaml.load(killed_run.config.read_text(), Loader=yaml.Loader)
    config.output_dir = tmp_path / "outputs"
    (run / "config.yml").write_text(yaml.dump(config), "utf8")
    with (run / "nerfstudio_models" / "step-000000006.ckpt").open("r+b") as checkpoint:
        checkpoint.truncate(100_000)

    def says_it_once(program: str, err: str) -> None:
        assert "Traceback" not in err, err
        said = [line for line in err.splitlines() if "does not load" in line]
        assert len(said) == 1, err
        assert re.fullmatch(rf"{program}: .*step-000000006\.ckpt: does not load \(truncated or corrupt: .*\); using "
                            r"step-000000003\.ckpt \(step 3\) instead\.", said[0]), said[0]

    command = [BIN / "ns-eval", "--load-config", str(run / "config.yml"), "--output-path", str(tmp_path / "eval.json")]
    result = subprocess.run(command, capture_output=True, text=True, env=command_env(), timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]
    says_it_once("ns-eval", result.stderr)
    assert Path(json.loads((tmp_path / "eval.json").read_text())["checkpoint"]).name == "step-000000003.ckpt"

    capfd.readouterr()
    monkeypatch.setattr(sys, "argv", ["ns-render"])
    DatasetRender(load_config=run / "config.yml", output_path=tmp_path / "renders", split="test",
                  rendered_output_names=["rgb"]).main()
    says_it_once("ns-render", capfd.readouterr().err)
    assert list((tmp_path / "renders" / "test" / "rgb").iterdir())

    monkeypatch.setattr(sys, "argv", ["ns-train", *train_arguments(
        killed_run.scene, tmp_path / "outputs", "resumed", "--max-num-iterations", "1",
        "--load-dir", str(run / "nerfstudio_models"))])
    ns_train()
    says_it_once("ns-train", capfd.readouterr().err)
    resumed = run_dir(tmp_path / "outputs", "resumed") / "nerfstudio_models"
    assert [path.name for path in saved_checkpoints(resumed)] == ["step-000000004.ckpt"]  # trained step 4


def save_state(folder: Path, step: int) -> Path:
    path = folder / f"step-{step:09d}.ckpt"
    torch.save({"step": step, "pipeline": {"weight": torch.full((1000,), float(step))}}, path)
    return path


def test_an_explicit_step_or_no_loadable_checkpoint_is_one_error(tmp_path: Path) -> None:
    save_state(tmp_path, 1)
    broken = save_state(tmp_path, 2)
    broken.write_bytes(broken.read_bytes()[:500])
    with pytest.raises(UserError, match=r"step-000000002\.ckpt: does not load \(truncated or corrupt"):
        last_good_checkpoint(tmp_path, 2)
    with pytest.raises(UserError, match=r"step-000000005\.ckpt: no such checkpoint \(--load-step is 5\)\. Choose "
                       r"another step with --load-step \(saved there: step-000000002\.ckpt, step-000000001\.ckpt\)"):
        last_good_checkpoint(tmp_path, 5)
    assert last_good_checkpoint(tmp_path, 1)[1]["step"] == 1
    (tmp_path / "step-000000001.ckpt").write_bytes(b"not a checkpoint")
    with pytest.raises(UserError) as error:
        last_good_checkpoint(tmp_path)
    message = str(error.value)
    assert "\n" not in message and message.startswith(f"{tmp_path}: none of its checkpoints loads")
    assert "1 older ones do not load either" in message and "train the model again" in message


def test_eval_loader_takes_ssnerf_runs_old_and_new_and_leaves_other_methods_to_nerfstudio(tmp_path: Path,
                                                                                         capsys) -> None:
    """A config.yml written before the trainer config moved to `engine/` names `method_configs`; it gets the
    last-good loader once `eval_setup` sets its `load_dir`. Another method's config still gets nerfstudio's."""
    from nerfstudio.engine.trainer import TrainerConfig
    from nerfstudio.utils import eval_utils

    save_state(tmp_path, 1)
    broken = save_state(tmp_path, 2)
    broken.write_bytes(broken.read_bytes()[:500])
    old = yaml.load("!!python/object:ssnerf_method.method_configs.SSNeRFTrainerConfig {}", Loader=yaml.Loader)
    assert isinstance(old, SSNeRFTrainerConfig)
    old.load_dir = tmp_path  # what eval_setup does before it loads
    loaded: List[int] = []
    pipeline = SimpleNamespace(load_pipeline=lambda state, step: loaded.append(step))
    assert eval_utils.eval_load_checkpoint(old, pipeline) == (tmp_path / "step-000000001.ckpt", 1)  # type: ignore
    assert loaded == [1] and "step-000000002.ckpt: does not load" in capsys.readouterr().err
    other = TrainerConfig(load_dir=tmp_path)
    with pytest.raises(RuntimeError, match="PytorchStreamReader"):  # nerfstudio's own loader, as before
        eval_utils.eval_load_checkpoint(other, pipeline)  # type: ignore[arg-type]


def test_a_broken_load_checkpoint_file_is_one_error_naming_it(tmp_path: Path) -> None:
    broken = save_state(tmp_path, 4)
    broken.write_bytes(broken.read_bytes()[:500])
    trainer = SimpleNamespace(config=SimpleNamespace(load_dir=None, load_checkpoint=broken))
    with pytest.raises(UserError, match=rf"^{re.escape(str(broken))}: does not load \(truncated or corrupt: .*\)\. "
                                        "Pass --load-dir its folder instead"):
        SSNeRFTrainer._load_checkpoint(trainer)  # type: ignore[arg-type]
    trainer.config.load_checkpoint = tmp_path / "step-000000005.ckpt"
    with pytest.raises(UserError, match="step-000000005.ckpt: no such checkpoint file"):
        SSNeRFTrainer._load_checkpoint(trainer)  # type: ignore[arg-type]


def fake_trainer(folder: Path, latest_only: bool = True) -> SimpleNamespace:
    """What `SSNeRFTrainer.save_checkpoint` uses of a trainer."""
    return SimpleNamespace(checkpoint_dir=folder, config=SimpleNamespace(save_only_latest_checkpoint=latest_only),
                           checkpoint_state=lambda step: {"step": step, "pipeline": {"weight": torch.ones(1000)}})


def test_older_checkpoints_are_deleted_only_after_the_new_one_is_whole(tmp_path: Path, monkeypatch) -> None:
    """A save that fails midway (here: torch fails after writing part of it) leaves the previous checkpoint as the
    only one, whole; a later save replaces it."""
    trainer = fake_trainer(tmp_path)
    SSNeRFTrainer.save_checkpoint(trainer, 3)  # type: ignore[arg-type]
    save = torch.save

    def failing_save(state, stream, *args, **kwargs):
        stream.write(b"PK\x03\x04 half a checkpoint")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(torch, "save", failing_save)
    with pytest.raises(OSError, match="No space left"):
        SSNeRFTrainer.save_checkpoint(trainer, 6)  # type: ignore[arg-type]
    assert sorted(path.name for path in tmp_path.iterdir()) == ["step-000000003.ckpt"]
    monkeypatch.setattr(torch, "save", save)
    SSNeRFTrainer.save_checkpoint(trainer, 9)  # type: ignore[arg-type]
    assert sorted(path.name for path in tmp_path.iterdir()) == ["step-000000009.ckpt"]
    assert read_checkpoint(tmp_path / "step-000000009.ckpt")["step"] == 9


def test_a_save_removes_what_a_killed_save_left_and_nothing_else(tmp_path: Path) -> None:
    """A leftover `.partial` whose writer is dead goes; one whose writer runs (another save in progress) stays."""
    host = socket.gethostname().replace(".", "_")
    dead = tmp_path / f".step-000000006.ckpt.{host}-{dead_pid()}.ab12cd34{PARTIAL_SUFFIX}"
    live = tmp_path / f".step-000000006.ckpt.{host}-{os.getpid()}.ef56ab78{PARTIAL_SUFFIX}"
    for path in (dead, live):
        path.write_bytes(b"half")
    SSNeRFTrainer.save_checkpoint(fake_trainer(tmp_path, latest_only=False), 9)  # type: ignore[arg-type]
    assert sorted(path.name for path in tmp_path.iterdir()) == sorted([live.name, "step-000000009.ckpt"])


def dead_pid() -> int:
    """The id of a process that has ended."""
    process = subprocess.Popen(["true"])
    process.wait()
    return process.pid


def test_moved_data_names_the_fix_each_command_has(tmp_path: Path, monkeypatch) -> None:
    """`ns-eval`, `ns-render` and `ns-viewer` have no --data (`ns-render dataset` does): they are told to edit the
    run's config.yml; `ns-train` keeps --data."""
    missing = tmp_path / "moved"
    for program in ("ns-eval", "ns-render", "ns-viewer", "ns-train"):
        monkeypatch.setattr(sys, "argv", [f"/venv/bin/{program}", "--load-config", "config.yml"])
        [fault] = validate_dataset(missing, contents=False).faults
        assert fault.startswith(f"{missing}: does not exist."), fault
        if program == "ns-train":
            assert "Point --data at" in fault and "config.yml" not in fault
        else:
            assert "set `data:` under `pipeline:` -> `datamanager:` in the run's config.yml" in fault
            assert ("--data" in fault) == (program == "ns-render"), fault


def test_moved_data_with_ns_eval_and_the_fix_it_names(killed_run, tmp_path: Path) -> None:
    """A real `ns-eval` on a run whose dataset has moved: one line, no traceback; editing `data:` in config.yml as
    it says makes the run load again."""
    scene = tmp_path / "scene"
    shutil.copytree(killed_run.scene, scene)
    config = yaml.load(killed_run.config.read_text(), Loader=yaml.Loader)
    config.pipeline.datamanager.data = scene
    saved = tmp_path / "config.yml"
    saved.write_text(yaml.dump(config), "utf8")
    scene.rename(tmp_path / "scene_moved")
    result = subprocess.run([BIN / "ns-eval", "--load-config", str(saved), "--output-path", str(tmp_path / "e.json")],
                            capture_output=True, text=True, env=command_env(), timeout=600)
    assert result.returncode == 1 and "Traceback" not in result.stderr, result.stderr
    [line] = [line for line in result.stderr.splitlines() if "does not exist" in line]
    assert line.startswith(f"ns-eval: {scene}: does not exist. If the dataset has moved, set `data:` under"), line

    text = saved.read_text()  # the user's edit: the datamanager's `data:` (a path object in the file) -> new folder
    edited, count = re.subn(r"(\n    data: )!!python/object/apply:pathlib\.PosixPath\n(    - .*\n)+",
                            rf"\g<1>{tmp_path / 'scene_moved'}\n", text)
    assert count == 1
    saved.write_text(edited)
    _, pipeline, checkpoint, _ = eval_setup(saved, test_mode="test")
    assert checkpoint.name == "step-000000006.ckpt" and len(pipeline.datamanager.eval_dataset) > 0
