"""The SS-NeRF trainer: nerfstudio's `Trainer` with checkpoints that survive a kill, and its config.

`SSNeRFTrainer` writes each checkpoint whole (`atomic.save_torch_atomic`) and only then deletes the older ones,
and resumes (`--load-dir`, `--load-checkpoint`) from the newest checkpoint that loads. `SSNeRFTrainerConfig` makes
the commands that load a saved run through nerfstudio's `eval_setup` (`ns-eval`, `ns-render`, `ns-viewer`,
`ns-export`, and this plugin's tools) do the same, through `load_for_eval`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, Tuple, Type

from nerfstudio.engine.trainer import Trainer, TrainerConfig
from nerfstudio.pipelines.base_pipeline import Pipeline
from nerfstudio.utils import profiler, writer
from nerfstudio.utils.decorators import check_main_thread
from nerfstudio.utils.rich_utils import CONSOLE

from ssnerf_method.atomic import remove_stale_partials, save_torch_atomic
from ssnerf_method.engine.checkpoints import (
    CheckpointUnreadable,
    checkpoint_path,
    checkpoint_step,
    last_good_checkpoint,
    no_checkpoint,
    read_checkpoint,
    saved_checkpoints,
)
from ssnerf_method.errors import UserError


class SSNeRFTrainer(Trainer):
    """nerfstudio's trainer; a kill while saving leaves the previous checkpoints intact, and a resume skips a
    checkpoint that does not load."""

    config: SSNeRFTrainerConfig

    def checkpoint_state(self, step: int) -> Dict[str, Any]:
        """What nerfstudio saves in a checkpoint."""
        pipeline = self.pipeline.module if hasattr(self.pipeline, "module") else self.pipeline  # DDP wraps it
        return {
            "step": step,
            "pipeline": pipeline.state_dict(),
            "optimizers": {name: optimizer.state_dict() for name, optimizer in self.optimizers.optimizers.items()},
            "schedulers": {name: scheduler.state_dict() for name, scheduler in self.optimizers.schedulers.items()},
            "scalers": self.grad_scaler.state_dict(),
        }

    def train(self) -> None:
        """nerfstudio's training loop, with the run's folder made first: every rank of a data-parallel run writes
        `dataparser_transforms.json`, and nerfstudio's check-then-mkdir of its folder races between them."""
        self.base_dir.mkdir(parents=True, exist_ok=True)
        super().train()

    @check_main_thread
    def save_checkpoint(self, step: int) -> None:
        """Save `step`'s checkpoint whole, then (with `save_only_latest_checkpoint`) delete the others; first remove
        what a killed save left in the folder."""
        remove_stale_partials(self.checkpoint_dir)
        path = checkpoint_path(self.checkpoint_dir, step)
        save_torch_atomic(self.checkpoint_state(step), path)
        if self.config.save_only_latest_checkpoint:
            for older in self.checkpoint_dir.glob("*.ckpt"):
                if older != path:
                    older.unlink(missing_ok=True)

    def _load_checkpoint(self) -> None:
        """Resume from `--load-dir`'s newest checkpoint that loads (or `--load-step`'s), or from `--load-checkpoint`."""
        load_dir, load_file = self.config.load_dir, self.config.load_checkpoint
        if load_dir is not None:
            path, state = last_good_checkpoint(load_dir, self.config.load_step, "--load-step")
            remove_stale_partials(load_dir)
        elif load_file is not None:
            if not load_file.is_file():
                raise UserError(f"{load_file}: no such checkpoint file. Pass a run's nerfstudio_models/step-*.ckpt, "
                                "or --load-dir its folder.")
            try:
                path, state = load_file, read_checkpoint(load_file)
            except CheckpointUnreadable as error:
                raise UserError(f"{load_file}: does not load ({error}). Pass --load-dir its folder instead, to "
                                "resume from the newest checkpoint there that loads.") from error
        else:
            super()._load_checkpoint()
            return
        self._start_step = state["step"] + 1
        self.pipeline.load_pipeline(state["pipeline"], state["step"])
        self.optimizers.load_optimizers(state["optimizers"])
        if "schedulers" in state and self.config.load_scheduler:
            self.optimizers.load_schedulers(state["schedulers"])
        self.grad_scaler.load_state_dict(state["scalers"])
        CONSOLE.print(f"Done loading Nerfstudio checkpoint from {path}")


@dataclass
class SSNeRFTrainerConfig(TrainerConfig):
    """nerfstudio's trainer config, training with `SSNeRFTrainer`. Setting `load_dir` (`ns-train --load-dir`, and
    `eval_setup` for `ns-eval`, `ns-render`, `ns-viewer`, `ns-export`) to a folder without checkpoints is one clear
    error instead of nerfstudio's `IndexError`, and makes `eval_setup` load through `load_for_eval`."""

    _target: Type = field(default_factory=lambda: SSNeRFTrainer)

    def __setattr__(self, name: str, value: Any) -> None:
        if name == "load_dir" and value is not None:
            folder = Path(value)
            if folder.is_dir() and not saved_checkpoints(folder):
                raise no_checkpoint(folder)
            use_last_good_checkpoint_in_eval()
        super().__setattr__(name, value)


def train_in_process(config: TrainerConfig) -> None:
    """`ns-train`'s main on `config`, leaving no event writer or profiler behind. nerfstudio keeps them in
    module-level lists that only grow: without this, every later training in the same process (a study's runs one
    after another, or on one Ray worker) also logs into the earlier runs' event files, and its profile adds to the
    first run's."""
    from nerfstudio.scripts.train import main as train_main  # (it loads every method, this plugin's, which imports us)

    writers, profilers = len(writer.EVENT_WRITERS), len(profiler.PROFILER)
    try:
        train_main(config)
    finally:
        for added in writer.EVENT_WRITERS[writers:]:
            if isinstance(added, writer.TensorboardWriter):
                added.tb_writer.close()
        del writer.EVENT_WRITERS[writers:], profiler.PROFILER[profilers:]


def load_for_eval(config: TrainerConfig, pipeline: Pipeline) -> Tuple[Path, int]:
    """nerfstudio's `eval_load_checkpoint` for an SS-NeRF run: the newest checkpoint in `config.load_dir` that loads
    (or `load_step`'s, if the config sets one) into `pipeline`; returns its path and step."""
    assert config.load_dir is not None
    path, state = last_good_checkpoint(config.load_dir, config.load_step, "load_step in config.yml")
    pipeline.load_pipeline(state["pipeline"], state["step"])
    CONSOLE.print(f":white_check_mark: Done loading checkpoint from {path}")
    return path, checkpoint_step(path)


def use_last_good_checkpoint_in_eval() -> None:
    """Route nerfstudio's `eval_utils.eval_load_checkpoint` to `load_for_eval` for SS-NeRF configs; every other
    method's config still goes to nerfstudio's own. Idempotent.

    Installed when a config's `load_dir` is set, which `eval_setup` does right before it loads the checkpoint: by
    then `eval_utils` has finished importing. (At this plugin's import it may not have: nerfstudio imports plugins
    while `eval_utils` is still importing, and its `def eval_load_checkpoint` would then replace this one.)"""
    from nerfstudio.utils import eval_utils

    original = eval_utils.eval_load_checkpoint
    if getattr(original, "ssnerf_last_good", False):
        return

    def eval_load_checkpoint(config: TrainerConfig, pipeline: Pipeline) -> Tuple[Path, int]:
        if isinstance(config, SSNeRFTrainerConfig):
            return load_for_eval(config, pipeline)
        return original(config, pipeline)

    eval_load_checkpoint.ssnerf_last_good = True  # type: ignore[attr-defined]
    eval_load_checkpoint.__doc__ = original.__doc__
    eval_utils.eval_load_checkpoint = eval_load_checkpoint
