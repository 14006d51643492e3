"""`ssnerf-process {images,video} SOURCE OUTPUT_DIR`: poses for your photos or video on a CPU, with no COLMAP binary.

    ssnerf-process images my_photos/ my_scene [--matching exhaustive|sequential] [--overwrite]
    ssnerf-process video clip.mp4 my_scene [--num-frames 100]

Writes the dataset `ns-process-data` writes (`images/`, `images_2/` ..., `colmap/sparse/0`, `transforms.json`,
`sparse_pc.ply`), posed by COLMAP's own Python bindings (pycolmap). Images that could not be posed are listed; a
capture where too few are ends in one line saying what to change.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Optional, Union

import tyro
from rich.progress import BarColumn, Progress, TaskID, TaskProgressColumn, TextColumn, TimeElapsedColumn
from rich.table import Table

from nerfstudio.utils.rich_utils import CONSOLE

from ssnerf_method.errors import UserError, exit_with
from ssnerf_method.importers.photos import (
    Matching,
    ProcessObserver,
    ProcessOptions,
    ProcessReport,
    gather_photos,
    gather_video,
    process_capture,
)


@dataclass
class ProcessImagesConfig(ProcessOptions):
    """Pose a folder of photos of one scene (one camera, one size) and write a nerfstudio dataset."""

    data: Annotated[tyro.conf.Positional[Path], tyro.conf.arg(metavar="PHOTOS")] = tyro.MISSING
    """Folder of photos (JPEG or PNG)."""
    output_dir: Annotated[tyro.conf.Positional[Path], tyro.conf.arg(metavar="OUTPUT_DIR")] = tyro.MISSING
    """Dataset folder to write (missing or empty, unless --overwrite)."""

    def run(self, observer: ProcessObserver) -> ProcessReport:
        return process_capture(self.data, self.output_dir, self,
                               lambda images, obs: gather_photos(self.data, images, obs), observer=observer)


@dataclass
class ProcessVideoConfig(ProcessOptions):
    """Pose frames of a video of one scene and write a nerfstudio dataset."""

    data: Annotated[tyro.conf.Positional[Path], tyro.conf.arg(metavar="VIDEO")] = tyro.MISSING
    """Video file (anything OpenCV's FFmpeg reads: MP4, MOV, ...)."""
    output_dir: Annotated[tyro.conf.Positional[Path], tyro.conf.arg(metavar="OUTPUT_DIR")] = tyro.MISSING
    """Dataset folder to write (missing or empty, unless --overwrite)."""
    num_frames: int = 100
    """Frames to take, spread evenly over the video."""
    matching: Matching = "sequential"
    """Which frame pairs are matched: each with its `--overlap` neighbours (`sequential`) or every pair."""

    def run(self, observer: ProcessObserver) -> ProcessReport:
        return process_capture(self.data, self.output_dir, self,
                               lambda images, obs: gather_video(self.data, images, self.num_frames, obs),
                               video=True, observer=observer)


Commands = Union[
    Annotated[ProcessImagesConfig, tyro.conf.subcommand("images")],
    Annotated[ProcessVideoConfig, tyro.conf.subcommand("video")],
]


class ProgressObserver(ProcessObserver):
    """One progress bar per stage (a running clock for matching, which reports no count)."""

    def __init__(self, progress: Progress) -> None:
        self.progress = progress
        self.task: Optional[TaskID] = None

    def _finish(self) -> None:
        if self.task is not None:
            total = self.progress.tasks[self.task].total or 1
            self.progress.update(self.task, total=total, completed=total)

    def stage(self, name: str, total: Optional[int]) -> None:
        self._finish()
        self.task = self.progress.add_task(name, total=total)

    def advance(self, steps: int = 1) -> None:
        if self.task is not None:
            self.progress.advance(self.task, steps)

    def done(self, name: str, seconds: float) -> None:
        self._finish()


def summary_table(report: ProcessReport) -> Table:
    table = Table(title=f"ssnerf-process: {len(report.registered)} of {report.num_images} images posed")
    table.add_column("stage")
    table.add_column("seconds", justify="right")
    for stage, seconds in report.seconds.items():
        table.add_row(stage, f"{seconds:.1f}")
    return table


def main(config: Union[ProcessImagesConfig, ProcessVideoConfig]) -> ProcessReport:
    """Run the stages with progress bars, then print what was posed, what was not, and the next command."""
    progress = Progress(TextColumn("{task.description}"), BarColumn(), TaskProgressColumn(), TimeElapsedColumn(),
                        console=CONSOLE)
    with progress:
        report = config.run(ProgressObserver(progress))
    CONSOLE.print(summary_table(report))
    CONSOLE.print(f"{report.num_points} sparse points, mean reprojection error {report.reprojection_error_px:.2f} px.",
                  highlight=False)
    if report.unregistered:
        CONSOLE.print(f"Not posed (left out of transforms.json): {', '.join(report.unregistered)}", soft_wrap=True,
                      highlight=False)
    CONSOLE.print(f"Wrote {report.output_dir / 'transforms.json'}. Next: ssnerf-label {report.output_dir}",
                  highlight=False)
    return report


def entrypoint() -> None:
    """Console script: one line naming the file or folder and the fix, instead of a traceback, for a bad capture."""
    config = tyro.cli(Commands, prog="ssnerf-process")  # type: ignore[call-overload]
    try:
        main(config)
    except UserError as err:
        exit_with(err, "ssnerf-process")


if __name__ == "__main__":
    entrypoint()
