"""`ssnerf-label`: make property labels (edges, keypoints, normals, shading, semantics) for a nerfstudio dataset."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Dict, List

import tyro
from rich.progress import BarColumn, Progress, TaskProgressColumn, TextColumn, TimeRemainingColumn
from rich.table import Table

from nerfstudio.engine.trainer import TrainerConfig
from nerfstudio.utils.rich_utils import CONSOLE, ItersPerSecColumn

from ssnerf_method.data.io import DatasetInputError, write_json_atomic
from ssnerf_method.data.transforms import Transforms, load_transforms
from ssnerf_method.engine.trainer import train_in_process
from ssnerf_method.errors import UserError, exit_with
from ssnerf_method.label_tool.label_dataset import (
    KEPT,
    LABELLED,
    LabelDatasetConfig,
    LabelReport,
    check_frames,
    frames_needing_depth,
    label_dataset,
    prepare_inputs,
)
from ssnerf_method.label_tool.paths import LABEL_FOLDER, output_path
from ssnerf_method.method_configs import short_run

DEPTH_MODEL_SMOOTHNESS = 0.1
"""The depth model's `depth_smoothness` regulariser weight (`benchmark_depth_from`: flat walls come out flat)."""
DEPTH_MODEL_TRANSFORMS = "transforms_depth_model.json"
"""The dataset's transforms without its split lists, beside it, which the depth model trains on: every frame."""


def depth_model_trainer(transforms: Transforms, output_dir: Path, steps: int, every_frame: bool = True
                        ) -> TrainerConfig:
    """The RGB-only ssnerf-lite whose rendered depth labels frames without depth. With `every_frame` it trains on
    every frame, the held-out ones too (written as `DEPTH_MODEL_TRANSFORMS`, nerfstudio's `eval_mode` "all"): it is a
    labeller, which sees each image as a depth sensor would, while the SS-NeRF trained on the labels holds them out."""
    data = transforms.path
    if every_frame:
        data = transforms.folder.resolve() / DEPTH_MODEL_TRANSFORMS  # absolute: the model loads from anywhere
        write_json_atomic(data, {key: value for key, value in transforms.meta.items()
                                 if not key.endswith("_filenames")})
    trainer = short_run("ssnerf-lite", data, output_dir, steps)
    if every_frame:
        trainer.pipeline.datamanager.dataparser.eval_mode = "all"  # type: ignore[attr-defined]
    trainer.pipeline.model.properties = ()  # type: ignore[attr-defined]
    trainer.pipeline.model.regularisers["depth_smoothness"].mult = DEPTH_MODEL_SMOOTHNESS  # type: ignore[attr-defined]
    trainer.experiment_name, trainer.timestamp = "rgb", f"steps{steps}"
    return trainer


def train_depth_model(config: LabelDatasetConfig, transforms: Transforms) -> None:
    """Without --depth-from, train (or reuse) the RGB-only ssnerf-lite whose rendered depth gives the frames without
    depth their normals and shading, and point --depth-from at it; nothing when no frame needs it."""
    if config.depth_from is not None or config.depth_model_steps <= 0:
        return
    frames = frames_needing_depth(config, transforms, model=True)
    if not frames:
        return
    check_frames(transforms, config)  # bad input stops here, not after the training
    prepare_inputs(config, transforms)
    folder = (output_path(config.output, transforms).parent / LABEL_FOLDER / "depth_model").resolve()
    trainer = depth_model_trainer(transforms, folder, config.depth_model_steps)
    checkpoint = trainer.get_checkpoint_dir() / f"step-{config.depth_model_steps - 1:09d}.ckpt"
    if not checkpoint.is_file():
        CONSOLE.rule(f"{len(frames)} frames have no depth: training an RGB-only ssnerf-lite on every frame for "
                     f"{config.depth_model_steps} steps to render it (--depth-model-steps)")
        train_in_process(trainer)
    else:
        CONSOLE.print(f"Rendering the depth of {len(frames)} frames with {trainer.get_base_dir()}", highlight=False)
    config.depth_from = trainer.get_base_dir() / "config.yml"


def suggest(config: LabelDatasetConfig, transforms: Transforms) -> List[Path]:
    """--suggest-frames / --suggest-clicks: write the suggestion files (labelling nothing) and print them."""
    from ssnerf_method.data.io import image_size
    from ssnerf_method.label_tool import suggest as suggestions
    from ssnerf_method.label_tool.sources import read_class_ids
    from ssnerf_method.properties import class_property, class_uncertainty

    if config.suggest_frames < 0 or config.suggest_clicks < 0:
        raise DatasetInputError(f"--suggest-frames {config.suggest_frames} / --suggest-clicks {config.suggest_clicks}:"
                                " must be 0 or more. Pass e.g. --suggest-frames 4.")
    if config.suggest_clicks and config.load_config is None:
        raise DatasetInputError(f"{transforms.path}: --suggest-clicks needs --load-config, the config.yml of a model "
                                "trained on this data with semantics (ns-train ssnerf-lite --data DATA), whose "
                                "uncertainty decides the questions.")
    model = None
    if config.load_config is not None:
        from ssnerf_method.label_tool.rendered_depth import load_depth_model

        model = load_depth_model(config.load_config, transforms)
        if config.suggest_clicks and not model.model.class_names:  # type: ignore[attr-defined]
            raise DatasetInputError(f"{config.load_config}: the model has no semantic classes. Declare them "
                                    "(ssnerf-label DATA --semantic-classes wall floor ...), train, and pass that run.")
    spec = class_property()
    frames = suggestions.training_frames(transforms)
    renders: Dict[str, Dict] = {}
    with Progress(TextColumn("{task.description}"), BarColumn(), TaskProgressColumn(),
                  TimeRemainingColumn(elapsed_when_finished=True, compact=True)) as progress:
        task = progress.add_task("Rendering the frames" if model is not None else "Reading depth", total=len(frames))
        views = suggestions.frame_views(transforms, frames, model, renders, lambda: progress.advance(task))
    written = []
    folder = output_path(config.output, transforms).parent
    if config.suggest_frames:
        annotated = [frame["file_path"] for frame in frames if spec.file_key in frame]
        source = "capture depth" if model is None else f"rendered depth of {config.load_config}"
        suggestion = suggestions.suggest_frames(views, config.suggest_frames, annotated, source)
        table = Table(title=f"Frames to annotate, in order (surface from the {source})")
        for column in ("#", "frame", "scene it adds", "scene seen"):
            table.add_column(column)
        seen = suggestion.annotated_share
        if annotated:
            table.add_row("-", f"{len(annotated)} annotated already", "", f"{100 * seen:.1f}%")
        for order, pick in enumerate(suggestion.picks, 1):
            seen += pick.added_share
            table.add_row(str(order), pick.file_path, f"{100 * pick.added_share:.1f}%", f"{100 * seen:.1f}%")
        CONSOLE.print(table)
        written.append(suggestions.write_frame_suggestion(folder, suggestion))
    if config.suggest_clicks:
        uncertainty, guesses, labelled, sizes = [], [], [], []
        for frame in frames:
            logits = renders[frame["file_path"]][spec.prediction_key]
            uncertainty.append(class_uncertainty(logits)[..., 0].cpu().numpy())
            guesses.append(logits.argmax(dim=-1).cpu().numpy())
            width, height = image_size(transforms.file(frame["file_path"]))
            sizes.append((width, height))
            labelled.append(read_class_ids(transforms.file(frame[spec.file_key]), width, height, None)
                            if spec.file_key in frame else None)
        clicks = suggestions.suggest_clicks(views, uncertainty, guesses, labelled,
                                            model.model.class_names, config.suggest_clicks,  # type: ignore[union-attr]
                                            sizes)
        path = suggestions.write_click_suggestion(folder, clicks, str(config.load_config))
        CONSOLE.print(f"{len(clicks)} pixels to answer, most uncertain first (uncertainty "
                      f"{clicks[0].uncertainty:.2f} to {clicks[-1].uncertainty:.2f}), on "
                      f"{len({click.file_path for click in clicks})} frames" if clicks else "No pixel to ask about.",
                      highlight=False)
        written.append(path)
    for path in written:
        CONSOLE.print(f"Wrote {path}", highlight=False)
    if config.suggest_clicks:
        CONSOLE.print(f"Answer: fill each \"class\" with a class name (null skips it), then: ssnerf-label "
                      f"{transforms.folder} --annotations {written[-1]}", highlight=False)
    return written


def report_table(report: LabelReport, num_frames: int) -> Table:
    """One row per property: frames labelled, kept, and skipped with each reason."""
    table = Table(title=f"ssnerf-label: {num_frames} frames")
    for column in ("property", "labelled", "kept", "skipped (why)"):
        table.add_column(column)
    for name, outcomes in report.outcomes.items():
        skipped = [f"{count}: {outcome.removeprefix('skipped: ')}" for outcome, count in outcomes.items()
                   if outcome not in (LABELLED, KEPT)]
        table.add_row(name, str(outcomes[LABELLED]), str(outcomes[KEPT]), "; ".join(skipped) or "0")
    return table


def main(config: LabelDatasetConfig) -> LabelReport:
    """Label the dataset with a progress bar (and one for the depth --depth-from renders), then print the
    per-property report."""
    transforms = load_transforms(config.data)
    if config.suggest_frames or config.suggest_clicks:
        suggest(config, transforms)
        return LabelReport(transforms_path=output_path(config.output, transforms))
    start = time.perf_counter()
    train_depth_model(config, transforms)
    progress = Progress(TextColumn("{task.description}"), BarColumn(), TaskProgressColumn(show_speed=True),
                        ItersPerSecColumn(suffix="frames/s"), TimeRemainingColumn(elapsed_when_finished=True,
                                                                                  compact=True))
    with progress:
        task = progress.add_task("Labelling frames", total=len(transforms.frames))
        depth_task = None
        num_depth = len(frames_needing_depth(config, transforms))
        if num_depth:
            depth_task = progress.add_task(f"Rendering depth ({config.depth_from_scale:g}x)", total=num_depth)
        report = label_dataset(config, transforms, on_frame=lambda: progress.advance(task),
                               on_depth=None if depth_task is None else lambda: progress.advance(depth_task))
    CONSOLE.print(report_table(report, len(transforms.frames)))
    for note in report.notes:
        CONSOLE.print(note, soft_wrap=True, highlight=False)
    if report.backup_path is not None:
        CONSOLE.print(f"Original kept as {report.backup_path}")
    CONSOLE.print(
        f"Wrote {report.transforms_path} in {time.perf_counter() - start:.1f} s. Train with: "
        f"ns-train ssnerf-lite --data {report.transforms_path if config.output else transforms.folder}"
    )
    return report


def entrypoint() -> None:
    """Console script: one line of error (naming the file and the fix) instead of a traceback for bad input."""
    config = tyro.cli(LabelDatasetConfig)
    try:
        main(config)
    except UserError as err:
        exit_with(err, "ssnerf-label")


if __name__ == "__main__":
    entrypoint()
