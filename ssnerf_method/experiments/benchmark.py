"""`ssnerf-benchmark`: the paper's Table 1 (SS-NeRF against the Heuristic and Hybrid baselines, per property) and
Table 2-left (RGB PSNR of NeRF against each single-property SS-NeRF) for any set of scenes, in one command.

Per scene it trains one SS-NeRF per property, an RGB-only NeRF and the all-properties SS-NeRF, scores them and the
baselines as `ns-eval` does, and writes `report.md`, `tables.json` and figures. Finished steps are kept, so a stopped
run resumes.
"""

from __future__ import annotations

import json
import time
from copy import deepcopy
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any, Callable, Dict, List, Literal, Optional, Tuple

import numpy as np
import torch

from nerfstudio.engine.schedulers import MultiStepSchedulerConfig
from nerfstudio.engine.trainer import TrainerConfig
from nerfstudio.pipelines.base_pipeline import Pipeline
from nerfstudio.utils.eval_utils import eval_setup
from nerfstudio.utils.rich_utils import CONSOLE

from ssnerf_method.atomic import save_torch_atomic, write_text_atomic
from ssnerf_method.data.spacing import dataset_spacing, pose_spacing
from ssnerf_method.engine.trainer import train_in_process
from ssnerf_method.evaluation.figures import property_grid, shown, shown_label
from ssnerf_method.evaluation.heuristic import (
    DepthSource,
    HeuristicBaseline,
    HeuristicBaselineConfig,
    nearest_view_copy,
)
from ssnerf_method.evaluation.hybrid import HybridBaseline, HybridBaselineConfig
from ssnerf_method.evaluation.scoring import score_predictor
from ssnerf_method.experiments.launcher import Job, LauncherOptions, exclusive, failure, launch
from ssnerf_method.experiments.report import BASELINE_ROWS, write_report
from ssnerf_method.method_configs import SHORT_RUN_STEPS, short_run
from ssnerf_method.properties import OPTIONAL_PROPERTIES, REGISTRY, PropertyName, PropertySpec, resolve_properties
from ssnerf_method.rendering.depth import rendered_z_depth
from ssnerf_method.rendering.palette import semantic_palette
from ssnerf_method.scene.make_scene import MakeSceneConfig, camera_path, make_scene

DEFAULT_STEPS = SHORT_RUN_STEPS

NERF = "nerf"
"""Run name of the RGB-only model (the Hybrid baseline's renderer and Table 2's NeRF row)."""
ALL = "ssnerf-all"
BASELINES = tuple(BASELINE_ROWS)
"""Rows of Table 1 that train no field: the paper's two baselines and the nearest training view copied (a floor)."""


@dataclass
class ModelRun:
    """One model to train on a scene: its run name (its folder), properties and model-config overrides."""

    name: str
    properties: Tuple[str, ...]
    """Properties trained besides RGB."""
    overrides: Dict[str, Any] = field(default_factory=dict)
    """`SSNeRFModelConfig` fields to set (e.g. {"branches": {"semantics": "v"}}, {"loss_weights": {"rgb": 0.0}})."""


def default_method() -> Literal["ssnerf-lite", "ssnerf"]:
    """The paper's model where there is a GPU to train it, the lite one elsewhere (as `ssnerf-demo`)."""
    return "ssnerf" if torch.cuda.is_available() else "ssnerf-lite"


@dataclass
class ScenesRunsConfig(LauncherOptions):
    """The options `ssnerf-benchmark` and every `ssnerf-study` share."""

    scenes: Tuple[Path, ...] = ()
    """Datasets in the SS-NeRF format. Default: two generated default scenes (seeds 0 and 1) in OUTPUT/scenes."""
    method: Literal["ssnerf-lite", "ssnerf"] = field(default_factory=default_method)
    """Architecture of every trained model (the NeRF too); default: `ssnerf` on a GPU, `ssnerf-lite` on a CPU."""
    output: Path = Path("benchmark_report")
    """Folder for the reports, the figures and every run (resumable; the benchmark and the studies share runs)."""
    steps: Optional[int] = None
    """Training steps per model (default: 1000 for ssnerf-lite, 20000 for ssnerf)."""
    lr_drop: Optional[float] = None
    """If set, learning rates stay constant, then drop x0.1 at this fraction of the steps (not the method's decay)."""
    quick: bool = False
    """A few minutes on a CPU (for CI): tiny scenes and models, tens of steps; the numbers mean nothing."""
    preset: Optional[Path] = None
    """A YAML file of these options (the repository's `configs/`: the paper's tables); flags typed after it win."""

    def __post_init__(self) -> None:
        if self.lr_drop is not None and not 0.0 < self.lr_drop < 1.0:
            raise ValueError(f"--lr-drop is a fraction of the steps, strictly between 0 and 1; got {self.lr_drop}")


@dataclass
class BenchmarkConfig(ScenesRunsConfig):
    """Train and score SS-NeRF and the baselines on scenes; write Table 1, Table 2-left and figures."""

    properties: Tuple[PropertyName, ...] = OPTIONAL_PROPERTIES
    """Properties benchmarked (each needs labels in the scenes)."""
    all_properties_model: bool = True
    """Also train one model on all properties (an extra row)."""
    figure_view: int = 0
    """Index of the test view shown in each scene's figure."""
    heuristic: HeuristicBaselineConfig = field(default_factory=HeuristicBaselineConfig)
    hybrid: HybridBaselineConfig = field(default_factory=HybridBaselineConfig)


def run_tag(config: ScenesRunsConfig) -> str:
    """What a run's training was, as a folder name: its step count and, if set, the learning-rate drop."""
    tag = f"{config.steps or DEFAULT_STEPS[config.method]}-steps"
    return tag if config.lr_drop is None else f"{tag}-lr-drop-{config.lr_drop:g}"


def quick_config(config: BenchmarkConfig) -> BenchmarkConfig:
    quick = deepcopy(config)
    quick.steps = config.steps or 30
    quick.hybrid = HybridBaselineConfig(width=8, depth=3, steps=30, batch_size=4)
    return quick


def shrink_for_quick(trainer: TrainerConfig) -> None:
    datamanager, model = trainer.pipeline.datamanager, trainer.pipeline.model  # type: ignore[attr-defined]
    datamanager.train_num_rays_per_batch = datamanager.eval_num_rays_per_batch = 256
    model.grid_levels, model.grid_max_res, model.grid_log2_hashmap_size, model.grid_hidden_dim = 4, 64, 14, 32
    model.decoder_width = 32
    model.num_proposal_samples, model.proposal_max_res, model.num_field_samples = (24,), (64,), 16


BENCHMARK_SCENE = dict(trajectory="walkthrough", normals="from-depth")
"""Default benchmark scenes: a walk as sparse as the paper's Replica scenes, not the demo's dense loop."""


def generated_scenes(config: BenchmarkConfig) -> List[Path]:
    """The default scenes, seeds 0 and 1 (tiny with --quick), generated once under OUTPUT/scenes/walkthrough_seed_N."""
    size = dict(width=40, height=30, num_frames=10) if config.quick else {}
    scenes = []
    for seed in (0, 1):
        root = config.output / "scenes" / f"walkthrough_seed_{seed}"
        if not (root / "transforms.json").is_file():
            make_scene(MakeSceneConfig(output_dir=root, seed=seed, overwrite=True, path_frames=0,  # type: ignore
                                       **BENCHMARK_SCENE, **size))
        scenes.append(root)
    return scenes


def scene_spacing(scene: Path) -> Dict[str, Any]:
    """How far the scene's test views are from its training views; for a generated scene, also the demo loop's."""
    spacing: Dict[str, Any] = dataset_spacing(scene)
    generator = json.loads((scene / "transforms.json").read_text()).get("ssnerf_scene")
    if generator and generator.get("trajectory") not in (None, "loop"):
        loop = MakeSceneConfig(output_dir=scene, seed=generator["seed"])
        poses = np.stack(camera_path("loop", loop.num_frames, loop.seed))  # type: ignore[arg-type]
        held_out = np.array([loop.is_test(frame) for frame in range(len(poses))])
        spacing["loop"] = pose_spacing(poses[~held_out], poses[held_out])
    return spacing


class SceneBenchmark:
    """Everything for one scene; each step's result is a file under `folder`, reused when present."""

    def __init__(self, config: BenchmarkConfig, scene: Path, name: str) -> None:
        self.config, self.scene, self.name = config, scene, name
        self.folder = config.output / "runs" / name
        self.steps = config.steps or DEFAULT_STEPS[config.method]
        self.tag = run_tag(config)
        """Runs and results are per method and schedule, so another --steps/--method/--lr-drop trains afresh."""

    def models(self) -> List[ModelRun]:
        runs = [ModelRun(NERF, ()), *(ModelRun(f"ssnerf-{name}", (name,)) for name in self.config.properties)]
        if self.config.all_properties_model:
            runs.append(ModelRun(ALL, tuple(self.config.properties)))
        return runs

    def trainer_config(self, run: ModelRun) -> TrainerConfig:
        trainer = short_run(self.config.method, self.scene, self.folder, self.steps)
        trainer.pipeline.model.properties = run.properties  # type: ignore[attr-defined]
        model = trainer.pipeline.model  # type: ignore[attr-defined]
        for key, value in run.overrides.items():  # a dict override adds to the method's (e.g. lite's losses)
            current = getattr(model, key)
            setattr(model, key, {**current, **value} if isinstance(current, dict) else deepcopy(value))
        trainer.experiment_name = run.name
        trainer.timestamp = self.tag
        if self.config.lr_drop is not None:
            milestone = int(round(self.config.lr_drop * self.steps))
            for optimizer in trainer.optimizers.values():
                optimizer["scheduler"] = MultiStepSchedulerConfig(max_steps=self.steps, gamma=0.1,
                                                                  milestones=(milestone,))
        if self.config.quick:
            shrink_for_quick(trainer)
        return trainer

    def run_dir(self, run: str) -> Path:
        """Where nerfstudio writes a run (config.yml, nerfstudio_models/) and where its metrics are kept."""
        return self.folder / run / self.config.method / self.tag

    def config_path(self, run: str) -> Path:
        return self.run_dir(run) / "config.yml"

    def checkpoint(self, run: str) -> Path:
        """The final checkpoint of a run (what `ns-eval` loads)."""
        return self.config_path(run).parent / "nerfstudio_models" / f"step-{self.steps - 1:09d}.ckpt"

    def train_and_score(self, run: ModelRun) -> Dict[str, float]:
        """Train one model unless its metrics exist; return its test metrics with `train_seconds`, `seed`, `config`."""
        result = self.run_dir(run.name) / "metrics.json"
        failed = self.failed(self.log(run.name))
        if failed is not None and not result.is_file():
            return {"failed": failed, "config": str(self.config_path(run.name))}
        with exclusive(self.run_dir(run.name).with_name(self.tag + ".lock")):
            if result.is_file():
                CONSOLE.print(f"[dim]{self.name}/{run.name}: done earlier, reusing {result}")
                metrics = json.loads(result.read_text())
            else:
                metrics = self.train_and_evaluate(run)
                write_text_atomic(result, json.dumps(metrics, indent=2))
        config, checkpoint = self.config_path(run.name), self.checkpoint(run.name)
        if metrics.get("train_seconds") is None and config.is_file() and checkpoint.is_file():
            # trained by an interrupted call: config.yml is written as training starts, the checkpoint as it ends
            metrics["train_seconds"] = round(checkpoint.stat().st_mtime - config.stat().st_mtime, 1)
        if metrics.get("seed") is None:
            metrics["seed"] = self.trainer_config(run).machine.seed
        return {**metrics, "config": str(config)}

    def train_and_evaluate(self, run: ModelRun) -> Dict[str, Any]:
        trainer = self.trainer_config(run)
        seconds = None
        if not self.checkpoint(run.name).is_file():
            what = ", ".join(run.properties) or "RGB only"
            CONSOLE.rule(f"{self.name}: training {run.name} ({what}) for {self.steps} steps")
            start = time.time()
            train_in_process(trainer)
            seconds = round(time.time() - start, 1)
        _, pipeline, _, _ = eval_setup(self.config_path(run.name), test_mode="test")
        metrics = pipeline.get_average_eval_image_metrics()
        metrics.update(train_seconds=seconds, seed=trainer.machine.seed)
        return metrics

    def log(self, run: str) -> Path:
        """A run's console output when a Ray worker trains it."""
        return self.run_dir(run) / "launcher.log"

    def failed(self, log: Path) -> Optional[Dict[str, str]]:
        """The failure a Ray launch recorded for the job logging to `log` (none locally: it retries in-process)."""
        return failure(log) if self.config.launcher != "local" else None

    def job(self, run: ModelRun, after: Tuple[str, ...] = ()) -> Job:
        """Training `run` as a launcher job (its key: the run's folder)."""
        return Job(key=f"{self.name}/{run.name}/{self.config.method}/{self.tag}",
                   work=partial(train_job, self.config, self.scene, self.name, run),
                   result=self.run_dir(run.name) / "metrics.json", log=self.log(run.name), after=after)

    def jobs(self) -> List[Job]:
        """Every model and every baseline (they read the RGB-only model) as launcher jobs."""
        models = [self.job(run) for run in self.models()]
        nerf = next(job.key for job, run in zip(models, self.models()) if run.name == NERF)
        baselines = [Job(key=f"{self.name}/{name}-{self.config.method}-{self.tag}",
                         work=partial(baseline_job, self.config, self.scene, self.name, name),
                         result=self.baseline_path(name), log=self.baseline_path(name).with_suffix(".log"),
                         after=(nerf,))
                     for name in BASELINES]
        return [*models, *baselines]

    def load(self, run: str) -> Pipeline:
        return eval_setup(self.config_path(run), test_mode="test")[1]

    def baseline_path(self, name: str) -> Path:
        """A baseline's scores (per method and schedule: the Hybrid scores the NeRF's renders)."""
        return self.folder / f"{name}-{self.config.method}-{self.tag}.json"

    def baseline(self, name: str) -> Dict[str, Any]:
        """A baseline's test-split scores (`heuristic`, `hybrid` or `nearest`), computed once."""
        result = self.baseline_path(name)
        failed = self.failed(result.with_suffix(".log"))
        if failed is not None and not result.is_file():
            return {"failed": failed}
        with exclusive(result.with_suffix(".lock")):
            if result.is_file():
                return json.loads(result.read_text())
            CONSOLE.rule(f"{self.name}: {name} baseline")
            nerf = self.load(NERF)
            specs = self.baseline_specs(nerf)
            num_classes = len(nerf.datamanager.train_dataset.metadata.get("semantic_classes", []))  # type: ignore
            if name == "heuristic":
                predict = self.heuristic(nerf, specs, num_classes).predict_view
            elif name == "nearest":
                predict = nearest_view_copy(nerf.datamanager.train_dataset, specs, num_classes,  # type: ignore
                                            self.config.heuristic.angle_weight)
            else:
                predict = self.hybrid(nerf, specs, num_classes).predictor(rgb_renderer(nerf))
            metrics = score_predictor(predict, self.test_dataset(nerf), specs, num_classes)
            write_text_atomic(result, json.dumps(metrics, indent=2))
        return metrics

    def run(self) -> Dict[str, Dict[str, Any]]:
        """Every model and baseline on this scene: name -> test metrics (or {"failed": ...} from a Ray launch)."""
        models = self.models()
        results = {}
        for number, run in enumerate(models, start=1):
            CONSOLE.print(f"[bold]{self.name}: model {number}/{len(models)}: {run.name}")
            results[run.name] = self.train_and_score(run)
        for name in BASELINES:
            results[name] = self.baseline(name)
        lost = [name for name, metrics in results.items() if "failed" in metrics]
        if lost:
            CONSOLE.print(f"[yellow]{self.name}: no figure, {', '.join(lost)} failed")
        else:
            nerf = self.load(NERF)
            specs = self.baseline_specs(nerf)
            self.figure(nerf, specs, len(nerf.datamanager.train_dataset.metadata.get("semantic_classes", [])))  # type: ignore
        return results

    def baseline_specs(self, pipeline: Pipeline) -> List[PropertySpec]:
        available = pipeline.datamanager.train_dataset.metadata.get("available_properties", ())  # type: ignore
        return [spec for spec in resolve_properties(self.config.properties) if spec.name in available]

    @staticmethod
    def test_dataset(pipeline: Pipeline):
        return pipeline.datamanager.eval_dataset  # type: ignore[attr-defined]

    def heuristic(self, pipeline: Pipeline, specs: List[PropertySpec], num_classes: int) -> HeuristicBaseline:
        """The Heuristic baseline with the dataset's depth maps, or the RGB NeRF's rendered depth where it has none."""
        train = pipeline.datamanager.train_dataset  # type: ignore[attr-defined]
        depth = None if train.depth_files is not None else rendered_depth(pipeline, train.cameras)
        return HeuristicBaseline(train, specs, num_classes, train.metadata["dataparser_scale"], self.config.heuristic,
                                 depth)

    def hybrid(self, pipeline: Pipeline, specs: List[PropertySpec], num_classes: int) -> HybridBaseline:
        """The Hybrid baseline's annotators, trained once and kept in `hybrid_networks.pt`."""
        train = pipeline.datamanager.train_dataset  # type: ignore[attr-defined]
        hybrid = HybridBaseline(train, specs, num_classes, self.config.hybrid)
        weights = self.folder / "hybrid_networks.pt"
        if weights.is_file():
            hybrid.networks.load_state_dict(torch.load(weights))
        else:
            history = hybrid.fit()
            save_torch_atomic(hybrid.networks.state_dict(), weights)
            for name, losses in history.items():
                first, last = np.mean(losses[:10]), np.mean(losses[-10:])
                CONSOLE.print(f"hybrid {name} annotator: training loss {first:.4f} -> {last:.4f}")
        return hybrid

    def figure(self, nerf: Pipeline, specs: List[PropertySpec], num_classes: int) -> Path:
        """Fig. 3 for one test view: ground truth, SS-NeRF (each property from its own model), Heuristic, Hybrid."""
        path = self.config.output / f"figure_{self.name}.png"
        test = self.test_dataset(nerf)
        index = min(self.config.figure_view, len(test) - 1)
        item, cameras = test[index], test.cameras
        palette = semantic_palette(num_classes, test.metadata.get("semantic_colors"))
        rgb_spec = REGISTRY["rgb"]
        columns = [rgb_spec, *specs]

        truth = {spec.name: shown_label(spec, item, num_classes, palette) for spec in columns}
        ssnerf: Dict[str, Optional[np.ndarray]] = {}
        for spec in specs:
            outputs = self.load(f"ssnerf-{spec.name}").model.render_camera(cameras[index : index + 1])
            ssnerf[spec.name] = shown(spec, outputs[spec.prediction_key], palette)
        rgb = rgb_renderer(nerf)(cameras, index)
        ssnerf["rgb"] = shown(rgb_spec, rgb, palette)
        heuristic = self.heuristic(nerf, specs, num_classes).predict_view(cameras, index)
        hybrid = self.hybrid(nerf, specs, num_classes).predict_image(rgb)
        rows = {
            "ground truth": truth,
            "SS-NeRF": ssnerf,
            "Heuristic": {spec.name: shown(spec, heuristic[spec.name], palette) for spec in specs},
            "Hybrid": {"rgb": shown(rgb_spec, rgb, palette),
                       **{spec.name: shown(spec, hybrid[spec.name], palette) for spec in specs}},
        }
        property_grid(path, columns, rows, f"{self.name}, test view {index} (RGB: NeRF render)")
        return path


def train_job(config: BenchmarkConfig, scene: Path, name: str, run: ModelRun) -> None:
    """Launcher jobs: train and score a run, or score a baseline (module level, so Ray can send them to a worker)."""
    SceneBenchmark(config, scene, name).train_and_score(run)


def baseline_job(config: BenchmarkConfig, scene: Path, name: str, baseline: str) -> None:
    SceneBenchmark(config, scene, name).baseline(baseline)


def rgb_renderer(pipeline: Pipeline) -> Callable[[object, int], torch.Tensor]:
    """Render RGB for camera `index` of a `Cameras` with a trained pipeline (CPU tensor, H x W x 3)."""

    def render(cameras, index: int) -> torch.Tensor:
        with torch.no_grad():
            return pipeline.model.render_camera(cameras[index : index + 1])["rgb"].cpu()

    return render


def rendered_depth(pipeline: Pipeline, cameras) -> DepthSource:
    """A trained pipeline's z-depth (world units) per camera index: the Heuristic's depth without depth maps."""

    def depth(index: int) -> np.ndarray:
        with torch.no_grad():
            outputs = pipeline.model.render_camera(cameras[index : index + 1])
        return rendered_z_depth(outputs)[..., 0].cpu().numpy().astype(np.float64)

    return depth


def run(config: BenchmarkConfig) -> Dict[str, Dict[str, Dict[str, float]]]:
    """The whole benchmark; returns scene -> row -> metrics and writes the report."""
    start = time.time()
    if config.quick:
        config = quick_config(config)
    config.output.mkdir(parents=True, exist_ok=True)
    scenes = list(config.scenes) or generated_scenes(config)
    plain = [scene.name for scene in scenes]
    names = [scene.name if plain.count(scene.name) == 1 else f"{scene.parent.name}_{scene.name}" for scene in scenes]
    benches = [SceneBenchmark(config, scene, name) for scene, name in zip(scenes, names)]
    launch(config, [job for bench in benches for job in bench.jobs()])
    results = {bench.name: bench.run() for bench in benches}
    spacing = {bench.name: scene_spacing(bench.scene) for bench in benches}
    report = write_report(config.output, results, list(config.properties), config.method,
                          config.steps or DEFAULT_STEPS[config.method], config.lr_drop, spacing)
    CONSOLE.print(report.read_text())
    CONSOLE.print(f"Benchmark done in {(time.time() - start) / 60:.1f} min: {report}")
    return results
