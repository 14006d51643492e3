"""nerfstudio checkpoints (`step-N.ckpt`), written whole and read back from the newest one that loads.

nerfstudio writes a checkpoint straight to its final name and reads the newest by name alone, so a training killed
while saving leaves a truncated newest checkpoint that every later command fails on, with a traceback. The SS-NeRF
trainer writes a checkpoint through `atomic.save_torch_atomic` (a `.partial` file renamed into place once on disk),
and a reader here skips a checkpoint that does not load, saying so in one line, for the next older one.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path
from typing import Any, Dict, List, Optional, Tuple

import torch

from ssnerf_method.errors import UserError

CHECKPOINT_NAME = re.compile(r"step-(\d+)\.ckpt")
"""A checkpoint's file name as nerfstudio writes it; the number is the training step."""
REQUIRED_KEYS = ("step", "pipeline")
"""What every nerfstudio checkpoint holds (training also reads "optimizers" and "scalers")."""


class CheckpointUnreadable(Exception):
    """A checkpoint file that torch cannot load, or that is not a nerfstudio checkpoint; the message says why."""


def checkpoint_path(folder: Path, step: int) -> Path:
    """Where nerfstudio keeps the checkpoint of `step` in `folder`."""
    return folder / f"step-{step:09d}.ckpt"


def checkpoint_step(path: Path) -> int:
    match = CHECKPOINT_NAME.fullmatch(path.name)
    assert match is not None, f"{path} is not named as a checkpoint"
    return int(match.group(1))


def saved_checkpoints(folder: Path) -> List[Path]:
    """The checkpoints in `folder`, newest (highest step) first; temporary files of unfinished saves are not among
    them."""
    found = [path for path in folder.glob("step-*.ckpt") if CHECKPOINT_NAME.fullmatch(path.name)]
    return sorted(found, key=checkpoint_step, reverse=True)


def read_checkpoint(path: Path) -> Dict[str, Any]:
    """The state saved in `path` (on the CPU); `CheckpointUnreadable` if it does not load."""
    try:
        state = torch.load(path, map_location="cpu")
    except MemoryError:
        raise
    except Exception as error:  # torch reports a truncated or corrupt file as RuntimeError, EOFError, pickle errors...
        why = str(error).strip().splitlines()[0].split(". ")[0] if str(error).strip() else type(error).__name__
        raise CheckpointUnreadable(f"truncated or corrupt: {why[:200]}") from error
    if not isinstance(state, dict) or any(key not in state for key in REQUIRED_KEYS):
        raise CheckpointUnreadable("not a nerfstudio checkpoint (no step or pipeline in it)")
    return state


def no_checkpoint(folder: Path) -> UserError:
    """The error for a checkpoint folder that holds no checkpoint."""
    return UserError(f"{folder}: holds no checkpoint (step-*.ckpt). Point at a run that saved one (training saves "
                     "every steps_per_save steps and at its end), or train longer.")


def warn(message: str) -> None:
    """One line on stderr, prefixed with the program's name, never wrapped."""
    from rich.console import Console
    from rich.markup import escape

    program = Path(sys.argv[0]).name if sys.argv and sys.argv[0] else "ssnerf"
    Console(stderr=True, soft_wrap=True, highlight=False).print(
        f"[bold yellow]{escape(program)}:[/bold yellow] {escape(message)}")


def last_good_checkpoint(folder: Path, step: Optional[int] = None,
                         step_option: str = "--load-step") -> Tuple[Path, Dict[str, Any]]:
    """The checkpoint of `step` in `folder` and its state, or with no `step` the newest one that loads: each newer
    one that does not is reported in one line naming it and the one used instead. `UserError` when none loads (or
    `step`'s is missing or does not load); `step_option` is how the user chose `step`, for that message."""
    if not folder.is_dir():
        raise UserError(f"{folder}: no such checkpoint folder. For --load-dir, point at a run's nerfstudio_models "
                        "folder; for a run's config.yml, a relative output_dir in it is taken from the current folder: "
                        "run the command from the folder training ran in, or make output_dir absolute.")
    saved = saved_checkpoints(folder)
    if step is not None:
        path = checkpoint_path(folder, step)
        names = ", ".join(other.name for other in saved) or "none"
        fix = (f"Choose another step with {step_option} (saved there: {names}), or unset {step_option} to use the "
               "newest checkpoint that loads.")
        if not path.is_file():
            raise UserError(f"{path}: no such checkpoint ({step_option} is {step}). {fix}")
        try:
            return path, read_checkpoint(path)
        except CheckpointUnreadable as error:
            raise UserError(f"{path}: does not load ({error}); {step_option} is {step}. {fix}") from error
    if not saved:
        raise no_checkpoint(folder)
    broken: List[Tuple[Path, CheckpointUnreadable]] = []
    for path in saved:
        try:
            state = read_checkpoint(path)
        except CheckpointUnreadable as error:
            broken.append((path, error))
            continue
        for skipped, error in broken:
            warn(f"{skipped}: does not load ({error}); using {path.name} (step {state['step']}) instead.")
        return path, state
    newest, error = broken[0]
    others = f"; {len(broken) - 1} older ones do not load either" if len(broken) > 1 else ""
    raise UserError(f"{folder}: none of its checkpoints loads ({newest.name}: {error}{others}). Copy an intact "
                    "step-*.ckpt of this run into it, or train the model again.")
