"""`ssnerf-make-scene`: the embedded room rendered as a dataset (`scene/make_scene.py`)."""

from __future__ import annotations

import sys
import time

import tyro

from ssnerf_method.scene.make_scene import MakeSceneConfig, make_scene


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
