"""`ssnerf-demo`: make the embedded default scene, train on it, evaluate every property, write renders.

Runs the same steps a user would type (`ssnerf-make-scene`, `ns-train`, `ns-eval`), in one process: the trained
checkpoint is reloaded through nerfstudio's `eval_setup`, exactly as `ns-eval` loads it. Results: a metrics table on
the console, `metrics.json`, `summary.png` (every property of one test view, ground truth above rendering; the docs'
first figure) and per test view one PNG per property (ground truth | rendering) under `renders/`.
"""

from __future__ import annotations

import json
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, Literal, Optional

import numpy as np
import torch
import tyro
from PIL import Image
from rich.table import Table

from nerfstudio.pipelines.base_pipeline import Pipeline
from nerfstudio.utils.eval_utils import eval_setup
from nerfstudio.utils.rich_utils import CONSOLE

from ssnerf_method.atomic import write_text_atomic
from ssnerf_method.engine.trainer import train_in_process
from ssnerf_method.evaluation.figures import display_image, property_grid
from ssnerf_method.evaluation.heuristic import nearest_view_copy
from ssnerf_method.evaluation.scoring import score_predictor
from ssnerf_method.method_configs import SHORT_RUN_STEPS, short_run
from ssnerf_method.model.ssnerf_model import SSNeRFModel
from ssnerf_method.scene.make_scene import FLY_THROUGH, MakeSceneConfig, make_scene

DEMO_STEPS = {"ssnerf-lite": 700, "ssnerf": SHORT_RUN_STEPS["ssnerf"]}
"""The demo's training steps per method. On the CPU fewer than the benchmark's 1000, so that `make demo` stays within
10 minutes end to end on 2 cores."""


@dataclass
class DemoConfig:
    """Make the default scene, train SS-NeRF on it, evaluate every property on the held-out views."""

    output_dir: Path = Path("demo_output")
    """Where the scene, the trained model, the metrics and the renders go."""
    method: Literal["auto", "ssnerf", "ssnerf-lite"] = "auto"
    """Method to train; "auto" picks `ssnerf` on a CUDA GPU and `ssnerf-lite` on the CPU."""
    max_num_iterations: Optional[int] = None
    """Training steps (default: `DEMO_STEPS`, 700 for ssnerf-lite on the CPU, 20000 for ssnerf on a GPU)."""
    width: int = 128
    """Scene image width."""
    height: int = 96
    """Scene image height."""
    num_frames: int = 60
    """Scene frames (every 5th is a test view)."""
    seed: int = 0
    """Scene seed."""
    summary_view: int = 0
    """Test view of `summary.png`, the grid of every property (ground truth above SS-NeRF)."""
    eval_step_zero: bool = False
    """Also score the untrained model (step 0), to show what training adds."""
    overwrite: bool = False
    """Replace an earlier demo run in OUTPUT_DIR."""


def nearest_view_baseline(pipeline: Pipeline) -> Dict[str, float]:
    """Score of copying the nearest training view's labels (`evaluation.heuristic.nearest_view_copy`), with the
    split-level metrics `ns-eval` reports."""
    model: SSNeRFModel = pipeline.model  # type: ignore[assignment]
    train, test = pipeline.datamanager.train_dataset, pipeline.datamanager.eval_dataset  # type: ignore[attr-defined]
    return score_predictor(nearest_view_copy(train, model.specs, model.num_classes), test, model.specs,
                           model.num_classes)


def evaluate(
    pipeline: Pipeline, renders_dir: Optional[Path], summary: Optional[Path] = None, summary_view: int = 0
) -> Dict[str, float]:
    """The test split's metrics as `ns-eval` computes them; optionally ground truth | rendering PNGs per view, and
    `summary`: one grid of every property (ground truth above SS-NeRF) on test view `summary_view`. Each view is
    rendered once, for its metrics and its PNGs."""
    model: SSNeRFModel = pipeline.model  # type: ignore[assignment]
    grid: Dict[str, Dict[str, Optional[np.ndarray]]] = {"ground truth": {}, "SS-NeRF": {}}

    def save_renders(view: int, camera, batch: Dict[str, torch.Tensor], outputs: Dict[str, torch.Tensor]) -> None:
        assert renders_dir is not None
        view_dir = renders_dir / f"test_view_{view:02d}"
        view_dir.mkdir(parents=True, exist_ok=True)
        for spec in model.specs:
            label = spec.label(batch, model.num_classes).to(model.device)
            truth = display_image(spec.display(spec.kind.label_as_prediction(label, model.num_classes), model.palette))
            shown = display_image(spec.display(outputs[spec.prediction_key], model.palette))
            Image.fromarray(np.concatenate([truth, shown], axis=1)).save(view_dir / f"{spec.name}.png")
            if view == summary_view:
                grid["ground truth"][spec.name], grid["SS-NeRF"][spec.name] = truth, shown

    scores = pipeline.get_average_image_metrics(  # type: ignore[call-arg]
        pipeline.datamanager.fixed_indices_eval_dataloader, "eval",  # type: ignore[attr-defined]
        on_view=save_renders if renders_dir is not None else None,
    )
    scores = {name: value for name, value in scores.items() if name not in ("num_rays_per_sec", "fps")}
    if renders_dir is not None and summary is not None:
        property_grid(summary, model.specs, grid, f"Test view {summary_view} of the default scene: ground truth "
                      "(top) and SS-NeRF's renders (bottom), every property from one field")
    return scores


def print_table(columns: Dict[str, Dict[str, float]]) -> None:
    table = Table(title="SS-NeRF on the default scene's test views")
    table.add_column("metric")
    for title in columns:
        table.add_column(title, justify="right")
    names = list(next(iter(columns.values())))
    for name in names:
        table.add_row(name, *(f"{column.get(name, float('nan')):.4f}" for column in columns.values()))
    CONSOLE.print(table)


def run(config: DemoConfig) -> Dict[str, Dict[str, float]]:
    start = time.time()
    if config.output_dir.exists() and any(config.output_dir.iterdir()):
        if not config.overwrite:
            raise SystemExit(f"{config.output_dir} already holds a demo run; pass --overwrite to replace it.")
        shutil.rmtree(config.output_dir)
    scene_dir = config.output_dir / "scene"
    make_scene(MakeSceneConfig(scene_dir, config.width, config.height, config.num_frames, config.seed))

    method = config.method
    if method == "auto":
        method = "ssnerf" if torch.cuda.is_available() else "ssnerf-lite"
    trainer_config = short_run(method, scene_dir, config.output_dir / "runs",
                               config.max_num_iterations or DEMO_STEPS[method])
    trainer_config.timestamp = "demo"
    CONSOLE.rule(f"Training {method} for {trainer_config.max_num_iterations} steps on {scene_dir}")
    CONSOLE.print(
        f"(the same as: ns-train {method} --data {scene_dir} --max-num-iterations {trainer_config.max_num_iterations})"
    )
    train_start = time.time()
    train_in_process(trainer_config)
    train_seconds = time.time() - train_start

    config_path = trainer_config.get_base_dir() / "config.yml"
    CONSOLE.rule("Evaluating on the test views (checkpoint loaded as ns-eval does)")
    _, pipeline, _, step = eval_setup(config_path, test_mode="test")
    renders = evaluate(pipeline, config.output_dir / "renders", config.output_dir / "summary.png", config.summary_view)
    results: Dict[str, Dict[str, float]] = {f"{method} (step {step})": renders}
    results["nearest training view"] = nearest_view_baseline(pipeline)
    if config.eval_step_zero:
        untrained = trainer_config.pipeline.setup(device=pipeline.device, test_mode="test")
        results[f"{method} (step 0)"] = evaluate(untrained, None)

    summary = {
        "method": method,
        "steps": step,
        "train_seconds": round(train_seconds, 1),
        "total_seconds": round(time.time() - start, 1),
        "config": str(config_path),
        "results": results,
    }
    write_text_atomic(config.output_dir / "metrics.json", json.dumps(summary, indent=2))
    print_table(results)
    names = " ".join(spec.name for spec in pipeline.model.specs)  # type: ignore[attr-defined]
    CONSOLE.print(
        f"Trained in {train_seconds / 60:.1f} min; demo took {(time.time() - start) / 60:.1f} min.\n"
        f"Metrics: {config.output_dir / 'metrics.json'}\n"
        f"Every property on one view: {config.output_dir / 'summary.png'}"
        f"\nRenders (ground truth | SS-NeRF): "
        f"{config.output_dir / 'renders'}\nModel config: {config_path}  (try: ns-eval --load-config {config_path} "
        f"--output-path eval.json)\nBrowse every property: ns-viewer --load-config {config_path}\n"
        f"Fly-through video of every property: ns-render camera-path --load-config {config_path} "
        f"--camera-path-filename {scene_dir / FLY_THROUGH} --rendered-output-names {names} "
        f"--output-path {config.output_dir / 'fly_through.mp4'}"
    )
    return results


def entrypoint() -> None:
    """CLI entry point of `ssnerf-demo`."""
    run(tyro.cli(DemoConfig))


if __name__ == "__main__":
    entrypoint()
