"""`ssnerf-study transfer`: knowledge transfer between properties with limited views (the paper's Table 5).

Per scene, each source's SS-NeRF is trained on all training views and the target's on k evenly spaced views, from
scratch ("Limited Views") and with F_enc initialised from each source (`encoder_init`). The k-view copy lists every
frame of the scene, so poses are oriented and scaled as for the source model, whose F_enc lives in that frame.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Dict, List, Tuple

import numpy as np

from nerfstudio.utils.rich_utils import CONSOLE

from ssnerf_method.data.dataparser import SSNeRFDataParserConfig
from ssnerf_method.data.dataset import SSNeRFDataset
from ssnerf_method.data.io import StagedOutputFolder
from ssnerf_method.evaluation.figures import image_grid, shown, shown_label
from ssnerf_method.experiments.benchmark import BenchmarkConfig, ModelRun, SceneBenchmark, generated_scenes
from ssnerf_method.experiments.launcher import Job, launch
from ssnerf_method.experiments.report import average, headline, markdown, property_columns
from ssnerf_method.experiments.studies import RUN_RECORD, Results, StudyConfig, single, write_study_report
from ssnerf_method.properties import REGISTRY, PropertyName
from ssnerf_method.rendering.palette import semantic_palette

LIMITED = "Limited Views"
"""Row of the target trained from scratch on the k views."""
PATH_KEYS = ("file_path", "depth_file_path", "mask_path")
"""Per-frame path keys of nerfstudio's format (the registry adds each property's)."""


def evenly_spaced(names: List[str], k: int) -> List[str]:
    """k of `names` (in trajectory order), evenly spaced from the first to the last."""
    if not 1 <= k <= len(names):
        raise ValueError(f"--views {k}: the scene has {len(names)} training views; choose 1 to {len(names)}.")
    return [names[int(i)] for i in np.linspace(0, len(names) - 1, k).round()]


def make_limited_dataset(scene: Path, destination: Path, k: int) -> List[str]:
    """Write `destination/transforms.json`: the scene with k evenly spaced training views; returns them (relative)."""
    parser = SSNeRFDataParserConfig(data=scene).setup()
    train = [Path(name) for name in parser.get_dataparser_outputs("train").image_filenames]
    test = [Path(name) for name in parser.get_dataparser_outputs("test").image_filenames]
    root = scene.resolve()
    chosen = evenly_spaced([str(name.resolve().relative_to(root)) for name in train], k)
    meta = json.loads((scene / "transforms.json").read_text())
    keys = {*PATH_KEYS, *(spec.file_key for spec in REGISTRY.values() if spec.file_key is not None)}
    for frame in meta["frames"]:
        frame.update({key: str(root / frame[key]) for key in keys if key in frame})
    meta["train_filenames"] = [str(root / name) for name in chosen]
    meta["val_filenames"] = meta["test_filenames"] = [str(name.resolve()) for name in test]
    meta["ssnerf_limited_views"] = {"scene": str(root), "views": k, "train_filenames": chosen}
    with StagedOutputFolder(destination, overwrite=True) as folder:
        (folder / "transforms.json").write_text(json.dumps(meta, indent=2) + "\n")
    return chosen


def limited_scene(output: Path, scene: Path, k: int) -> Path:
    """`OUTPUT/limited/<scene>-<k>views`: the scene's k-view copy, made once and shared by transfer and sparsity."""
    root = output / "limited" / f"{scene.name}-{k}views"
    if not (root / "transforms.json").is_file():
        make_limited_dataset(scene, root, k)
    return root


@dataclass
class TransferStudy(StudyConfig):
    """Table 5: the target property on k views, from scratch and with F_enc transferred from each source."""

    target: PropertyName = "shading"
    """The property learnt from limited views (the paper's is SH)."""
    sources: Tuple[PropertyName, ...] = ("semantics", "normals", "keypoints", "edges")
    """Properties whose all-view SS-NeRF gives F_enc."""
    views: int = 6
    """Training views of the target (evenly spaced along the training trajectory)."""
    figure_view: int = 0
    """Test view shown in each scene's figure."""

    name = "transfer"
    scope = "Target trained on k training views; metrics on each scene's full test split, as `ns-eval` computes them."

    def row(self, source: str) -> str:
        return f"{REGISTRY[source].short} → {REGISTRY[self.target].short}"

    def target_run(self, source: str = "") -> ModelRun:
        if not source:
            return ModelRun(single(self.target), (self.target,))
        return ModelRun(f"{single(self.target)}-from-{source}", (self.target,))

    def benchmarks(self, config: BenchmarkConfig, scene: Path) -> Tuple[SceneBenchmark, SceneBenchmark]:
        """The scene with all its views (the sources) and its k-view copy (the target), made once."""
        limited_root = limited_scene(config.output, scene, self.views)
        return SceneBenchmark(config, scene, scene.name), SceneBenchmark(config, limited_root, limited_root.name)

    def transfer_runs(self, full: SceneBenchmark, source: str) -> Tuple[ModelRun, ModelRun]:
        """The all-view source model and the k-view target initialised with its F_enc."""
        source_run = ModelRun(single(source), (source,))
        overrides = {"encoder_init": full.checkpoint(source_run.name)}
        return source_run, ModelRun(self.target_run(source).name, (self.target,), overrides)

    def jobs(self, config: BenchmarkConfig, scenes: List[Path]) -> List[Job]:
        """The k-view target from scratch, each source, and each transferred target after its source."""
        jobs = []
        for scene in scenes:
            full, limited = self.benchmarks(config, scene)
            jobs.append(limited.job(self.target_run()))
            for source in self.sources:
                source_run, run = self.transfer_runs(full, source)
                source_job = full.job(source_run)
                jobs += [source_job, limited.job(run, after=(source_job.key,))]
        return jobs

    def run(self) -> Results:
        start = time.time()
        config = self.benchmark_config()
        config.output.mkdir(parents=True, exist_ok=True)
        scenes = list(config.scenes) or generated_scenes(config)
        results: Results = {}
        details: Dict[str, Any] = {}
        self.chosen: Dict[str, List[str]] = {}
        launch(config, self.jobs(config, scenes))
        for scene in scenes:
            full, limited = self.benchmarks(config, scene)
            meta = json.loads((limited.scene / "transforms.json").read_text())
            self.chosen[scene.name] = meta["ssnerf_limited_views"]["train_filenames"]
            CONSOLE.print(f"[bold]transfer study, {scene.name}: {self.target} on {self.views} views from scratch")
            runs = {LIMITED: (limited.train_and_score(self.target_run()), self.target_run(), {})}
            for source in self.sources:
                CONSOLE.print(f"[bold]transfer study, {scene.name}: {source} (all views), then {self.row(source)}")
                source_run, run = self.transfer_runs(full, source)
                full.train_and_score(source_run)
                runs[self.row(source)] = (limited.train_and_score(run), run, {"source_run": source_run.name})
            results[scene.name] = {row: metrics for row, (metrics, _, _) in runs.items()}
            details[scene.name] = {row: {"run": f"{limited.folder.name}/{run.name}", "properties": list(run.properties),
                                         "overrides": {key: str(value) for key, value in run.overrides.items()},
                                         **{key: metrics.get(key) for key in RUN_RECORD}, **extra}
                                   for row, (metrics, run, extra) in runs.items()}
            if not any("failed" in metrics for metrics, _, _ in runs.values()):
                self.figure(scene, limited, config.output / f"figure_transfer_{scene.name}.png")
        write_study_report(self, results, details, time.time() - start)
        return results

    def figure(self, scene: Path, limited: SceneBenchmark, path: Path) -> Path:
        """One test view: ground truth, the k-view target from scratch and each transferred one (RGB and target)."""
        spec, rgb_spec = REGISTRY[self.target], REGISTRY["rgb"]
        test = SSNeRFDataset(SSNeRFDataParserConfig(data=scene).setup().get_dataparser_outputs("test"))
        index = min(self.figure_view, len(test) - 1)
        palette = semantic_palette(test.num_classes, test.metadata.get("semantic_colors"))
        item = test[index]
        rows = {"ground truth": {key.name: shown_label(key, item, test.num_classes, palette)
                                 for key in (rgb_spec, spec)}}
        for title, source in [(LIMITED, ""), *((self.row(source), source) for source in self.sources)]:
            model = limited.load(self.target_run(source).name).model
            outputs = model.render_camera(test.cameras[index : index + 1].to(model.device))
            rows[title] = {key.name: shown(key, outputs[key.prediction_key], palette) for key in (rgb_spec, spec)}
        columns = [(rgb_spec.name, rgb_spec.short), (spec.name, spec.short)]
        image_grid(path, columns, rows, f"{scene.name}, test view {index}: {self.target} from {self.views} views")
        return path

    def tables(self, results: Results) -> Tuple[str, Dict[str, Any]]:
        key = headline(self.target)[0]
        columns = [*results, "average"]
        tables, texts = {}, []
        for index, measure in enumerate(property_columns(self.target)):
            rows = []
            for title in [LIMITED, *(self.row(source) for source in self.sources)]:
                values = {scene: runs.get(title, {}).get(measure.metric) for scene, runs in results.items()}
                rows.append({"row": title, **values, "average": average(list(values.values()))})
            tables["table5" if index == 0 else f"table5_{measure.metric}"] = rows
            texts.append(f"{measure.title} on the test views; the target sees {self.views} training views\n\n"
                         + markdown(rows, columns, columns, 4))
        views = "\n".join(f"- {scene}: {', '.join(names)}" for scene, names in getattr(self, "chosen", {}).items())
        text = ("\n\n".join(texts) + f"\n\nTraining views of the target:\n\n{views}\n\nFigures: "
                + ", ".join(f"`figure_transfer_{scene}.png`" for scene in results))
        return text, {**tables, "target": self.target, "metric": key, "views": self.views,
                      "train_views": getattr(self, "chosen", {})}
