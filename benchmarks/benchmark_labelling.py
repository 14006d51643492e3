"""Time `ssnerf-label` per frame, per label kind and all together, on frames of a chosen size.

    python -m benchmarks.benchmark_labelling [--width 640] [--height 480] [--num-frames 8] [--workers 2]

Renders the default scene at the requested size (RGB and depth are what `ssnerf-label` reads), lists only images and
depth in its transforms, then runs the labeller once per kind alone (one worker, so the times add up per frame) and
once with every kind and `--workers` threads, as the command runs by default. Each run writes a new transforms file
and fresh label images, so disk writes (PNG encoding) are included. Rendering the scene is not timed.
"""

from __future__ import annotations

import json
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Dict

import tyro
from rich.table import Table

from nerfstudio.utils.rich_utils import CONSOLE

from ssnerf_method.data.transforms import load_transforms
from ssnerf_method.label_tool.label_dataset import LabelDatasetConfig, label_dataset
from ssnerf_method.properties import OPTIONAL_PROPERTIES, REGISTRY, labelled_properties
from ssnerf_method.scene.make_scene import MakeSceneConfig, make_scene


@dataclass
class BenchmarkLabellingConfig:
    """Seconds per frame of `ssnerf-label` at one image size."""

    width: int = 640
    height: int = 480
    num_frames: int = 8
    workers: int = 2
    """Threads for the all-kinds run (the command's default is 2)."""


def unlabelled_scene(root: Path, config: BenchmarkLabellingConfig) -> Path:
    """The default scene at the benchmark's size, its transforms listing only images and depth."""
    make_scene(MakeSceneConfig(output_dir=root, width=config.width, height=config.height, num_frames=config.num_frames))
    meta = json.loads((root / "transforms.json").read_text())
    for frame in meta["frames"]:
        for name in OPTIONAL_PROPERTIES:
            frame.pop(REGISTRY[name].file_key)
    (root / "transforms.json").write_text(json.dumps(meta))
    return root


def timed_run(data: Path, name: str, workers: int, **switches: bool) -> float:
    config = LabelDatasetConfig(data=data, output=f"transforms_{name}.json", workers=workers, **switches)
    transforms = load_transforms(data)
    start = time.perf_counter()
    label_dataset(config, transforms)
    return time.perf_counter() - start


def main(config: BenchmarkLabellingConfig) -> Dict[str, float]:
    with tempfile.TemporaryDirectory() as folder:
        data = unlabelled_scene(Path(folder) / "scene", config)
        specs = labelled_properties()
        timed_run(data, "warmup", 1, **{spec.name: spec is specs[-1] for spec in specs})  # imports, lazy init
        seconds = {}
        for spec in specs:
            if spec.kind.categorical:
                continue  # class ids are never derived: a copy
            # a maker reading another's output (shading reads normals) is timed with it, minus that one's own time
            helpers = [other for other in specs if other.label_maker.provides in spec.label_maker.reads]
            switches = {other.name: other is spec or other in helpers for other in specs}
            seconds[spec.name] = timed_run(data, spec.name, 1, **switches) - sum(seconds[h.name] for h in helpers)
        seconds[f"all kinds, {config.workers} workers"] = timed_run(data, "all", config.workers)
    table = Table(title=f"ssnerf-label, {config.num_frames} frames of {config.width}x{config.height}")
    table.add_column("labels")
    table.add_column("s / frame")
    for name, total in seconds.items():
        table.add_row(name, f"{total / config.num_frames:.3f}")
    CONSOLE.print(table)
    return {name: total / config.num_frames for name, total in seconds.items()}


def entrypoint() -> None:
    main(tyro.cli(BenchmarkLabellingConfig))


if __name__ == "__main__":
    entrypoint()
