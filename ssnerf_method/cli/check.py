"""`ssnerf-check DATA`: check a dataset against the SS-NeRF format and list every fault, before training on it."""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path

import tyro

from nerfstudio.utils.rich_utils import CONSOLE

from ssnerf_method.data.validate import validate_dataset


@dataclass
class CheckConfig:
    """Check a dataset (transforms.json, poses, cameras, images, depth and every property label) as `ns-train` will,
    and list every fault, one line each naming the file or frame and the fix. Exit status 1 when there is any."""

    data: tyro.conf.Positional[Path]
    """Dataset folder holding transforms.json (or the path of a transforms .json file)."""
    contents: bool = True
    """Read the label pixels too (class ids in range, unit normals, depth not all zero); off, headers only."""
    workers: int = 4
    """Files checked in parallel (threads)."""


def main(config: CheckConfig) -> int:
    """Print the faults (stderr, one line each) and a one-line summary (stdout); return the exit status."""
    start = time.perf_counter()
    validation = validate_dataset(config.data, contents=config.contents, workers=config.workers)
    seconds = time.perf_counter() - start
    for fault in validation.faults:
        print(f"ssnerf-check: {fault}", file=sys.stderr)
    if validation.faults:
        CONSOLE.print(f"{len(validation.faults)} fault(s) in {validation.transforms_path}.", soft_wrap=True,
                      highlight=False)
        return 1
    labels = ", ".join(f"{name} {count}" for name, count in validation.labelled.items()) or "none"
    CONSOLE.print(
        f"{validation.transforms_path}: OK, {validation.num_frames} frames; frames with labels: {labels} "
        f"({seconds:.1f} s). Train with: ns-train ssnerf-lite --data {config.data}",
        soft_wrap=True, highlight=False,
    )
    return 0


def entrypoint() -> None:
    """Console script."""
    sys.exit(main(tyro.cli(CheckConfig)))


if __name__ == "__main__":
    entrypoint()
