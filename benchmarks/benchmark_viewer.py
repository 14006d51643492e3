"""Time one viewer frame of a trained model at the image heights nerfstudio's viewer renders.

    python -m benchmarks.benchmark_viewer --load-config outputs/.../config.yml [--heights 30 60 120 384]
        [--threads 1]

The viewer renders every frame through `get_outputs_for_camera` (all display outputs at once, whichever is shown).
While the camera moves it picks the image height that its measured rays per second allow at 24 frames per second
(never below 30 px); once the camera rests it renders at "Max res" (512 by default). This times that call for the
first test camera resized to each height (aspect kept), after one warm-up frame, and prints milliseconds per frame
and the height the viewer would choose while moving.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Tuple

import torch
import tyro
from rich.table import Table

from nerfstudio.utils.eval_utils import eval_setup
from nerfstudio.utils.rich_utils import CONSOLE

VIEWER_TARGET_FPS = 24
"""nerfstudio's viewer target while the camera moves (`RenderStateMachine.target_fps`)."""


@dataclass
class BenchmarkViewerConfig:
    """Milliseconds per viewer frame at several image heights."""

    load_config: Path
    """config.yml of the trained model."""
    heights: Tuple[int, ...] = (30, 60, 120, 240, 384)
    """Image heights to time (384 is the height of a 512-wide frame at 4:3, the viewer's resting "Max res")."""
    repeats: int = 3
    """Frames timed per height (the median is reported)."""
    threads: Optional[int] = None
    """torch CPU threads (default: torch's choice). On 2 shared cores, 2 threads stall whenever another process is
    busy; 1 thread gives steadier frame times there."""


def main(config: BenchmarkViewerConfig) -> None:
    if config.threads:
        torch.set_num_threads(config.threads)
    _, pipeline, _, step = eval_setup(config.load_config, test_mode="test")
    model = pipeline.model
    camera = pipeline.datamanager.eval_dataset.cameras[0:1]  # type: ignore[attr-defined]
    aspect = float(camera.width) / float(camera.height)
    table = Table(title=f"Viewer frame time, {config.load_config} (step {step}, {torch.get_num_threads()} threads)")
    for column in ("height", "width", "rays", "ms / frame", "frames / s", "rays / s"):
        table.add_column(column, justify="right")
    rays_per_second = 0.0
    for height in config.heights:
        scaled = camera[0:1]
        scaled.rescale_output_resolution(height / float(camera.height))
        model.get_outputs_for_camera(scaled)  # warm-up
        times = []
        for _ in range(config.repeats):
            start = time.perf_counter()
            model.get_outputs_for_camera(scaled)
            times.append(time.perf_counter() - start)
        seconds = sorted(times)[len(times) // 2]
        rays = int(scaled.width) * int(scaled.height)
        rays_per_second = max(rays_per_second, rays / seconds)
        table.add_row(str(int(scaled.height)), str(int(scaled.width)), str(rays), f"{seconds * 1000:.0f}",
                      f"{1 / seconds:.1f}", f"{rays / seconds:.0f}")
    CONSOLE.print(table)
    moving = max(30, int(round((rays_per_second / VIEWER_TARGET_FPS / aspect) ** 0.5, -1)))
    CONSOLE.print(f"While the camera moves the viewer would render about {int(moving * aspect)}x{moving} "
                  f"({rays_per_second:.0f} rays/s at {VIEWER_TARGET_FPS} fps target).")


if __name__ == "__main__":
    main(tyro.cli(BenchmarkViewerConfig))
