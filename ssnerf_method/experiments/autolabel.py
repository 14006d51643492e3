"""`ssnerf-study autolabel`: how far SS-NeRF cleans weak labels (the paper's auto-labelling use, Fig. 4, measured).

With no pre-trained annotator here, weak labels are clean labels corrupted per view (`label_makers/corruptions.py`).
Per scene and rate it writes a weak copy (`OUTPUT/weak/<scene>-<property>-<rate>/`), trains the single-property
SS-NeRF on it, and scores the weak labels and the renders against the clean labels at the training and test views.
"""

from __future__ import annotations

import json
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Dict, List, Literal, Tuple

import numpy as np
from PIL import Image

from nerfstudio.utils.rich_utils import CONSOLE

from ssnerf_method.atomic import write_text_atomic
from ssnerf_method.data.dataparser import SSNeRFDataParserConfig
from ssnerf_method.data.dataset import SSNeRFDataset
from ssnerf_method.data.io import StagedOutputFolder, encode_png
from ssnerf_method.evaluation.figures import image_grid, shown, shown_label
from ssnerf_method.evaluation.scoring import score_predictor
from ssnerf_method.experiments.benchmark import BenchmarkConfig, ModelRun, SceneBenchmark, generated_scenes
from ssnerf_method.experiments.launcher import Job, launch
from ssnerf_method.experiments.report import Column, average, markdown, property_columns
from ssnerf_method.experiments.studies import RUN_RECORD, Results, StudyConfig, single, write_study_report
from ssnerf_method.label_makers.corruptions import DEFAULT_RATES, corrupt_label_file
from ssnerf_method.properties import REGISTRY, PropertyName, PropertySpec
from ssnerf_method.rendering.palette import semantic_palette


def suffix(measure: Column) -> str:
    """What a score's name adds for a measure beside the headline (which keeps the plain name)."""
    return "" if measure.key == measure.prop else f" ({measure.metric})"


COLUMNS = ("weak labels, training views", "SS-NeRF, training views", "weak labels, test views", "SS-NeRF, test views")


def make_weak_dataset(
    clean: Path, destination: Path, spec: PropertySpec, rate: float, mode: Literal["pixels", "regions"], seed: int
) -> Path:
    """A copy of the dataset at `clean` whose `spec` labels are corrupted at `rate`, frame i with seed (seed, i)."""
    meta = json.loads((clean / "transforms.json").read_text())
    num_classes = len(meta.get("semantic_classes", []))
    with StagedOutputFolder(destination, overwrite=True) as folder:
        shutil.copytree(clean, folder, dirs_exist_ok=True)
        for index, frame in enumerate(meta["frames"]):
            if spec.file_key not in frame:
                continue
            path = folder / frame[spec.file_key]
            with Image.open(path) as image:
                label = np.asarray(image)
            weak = corrupt_label_file(label, spec.corruption, rate, num_classes, np.random.default_rng([seed, index]),
                                      mode)
            path.write_bytes(encode_png(weak))
        meta["ssnerf_weak_labels"] = {"property": spec.name, "corruption": spec.corruption, "rate": rate,
                                      "mode": mode, "seed": seed, "clean": str(clean.resolve())}
        (folder / "transforms.json").write_text(json.dumps(meta, indent=2) + "\n")
    return destination / "transforms.json"


@dataclass
class AutoLabelStudy(StudyConfig):
    """Weak labels (clean ones corrupted per view) against SS-NeRF trained on them, both scored on clean labels."""

    target: PropertyName = "semantics"
    """The property given weak labels."""
    rates: Tuple[float, ...] = ()
    """Corruption rates (default per corruption: semantics 0.1 0.3 0.5 of the pixels; normals and shading a mean
    change of 0.02 0.05 0.1; edges and keypoints 0.2 0.4 0.6 of the responses dropped and as many added)."""
    mode: Literal["pixels", "regions"] = "pixels"
    """Semantics only: pixel-wise noise or whole-region class swaps."""
    seed: int = 0
    """Seed of the corruptions (frame i uses (seed, i))."""
    figure_view: int = 0
    """Training view of the first scene shown in the figure."""

    name = "autolabel"
    scope = "Metrics against the clean labels at each scene's training and test views, computed as `ns-eval` does."

    def chosen_rates(self) -> Tuple[float, ...]:
        return self.rates or DEFAULT_RATES[REGISTRY[self.target].corruption]

    def run(self) -> Results:
        """Weak copies, trained models and scores for every scene and rate; then the report."""
        start = time.time()
        spec = REGISTRY[self.target]
        if spec.corruption == "none":
            raise ValueError(f"{self.target} has no weak-label corruption; choose a labelled property")
        config = self.benchmark_config()
        config.output.mkdir(parents=True, exist_ok=True)
        clean_scenes = list(config.scenes) or generated_scenes(config)
        results: Results = {}
        run = ModelRun(single(self.target), (self.target,))
        launch(config, self.jobs(config, clean_scenes))
        for clean in clean_scenes:
            for rate in self.chosen_rates():
                bench = self.weak_benchmark(config, clean, rate)
                trained = bench.train_and_score(run)
                scores = self.score(clean, bench.scene, bench, run, spec) if "failed" not in trained else {
                    "failed": trained["failed"]}
                results.setdefault(clean.name, {})[f"{rate:g}"] = {
                    **scores, **{key: trained.get(key) for key in RUN_RECORD}}
        if not any("failed" in row for rows in results.values() for row in rows.values()):
            self.figure(clean_scenes[0], config, spec)
        runs = {scene: {rate: {key: values.get(key) for key in RUN_RECORD}
                        for rate, values in by_rate.items()} for scene, by_rate in results.items()}
        write_study_report(self, results, runs, time.time() - start)
        return results

    def jobs(self, config: BenchmarkConfig, scenes: List[Path]) -> List[Job]:
        """The target's SS-NeRF on every weak copy (made here, before the launcher runs them)."""
        run = ModelRun(single(self.target), (self.target,))
        return [self.weak_benchmark(config, clean, rate).job(run) for clean in scenes for rate in self.chosen_rates()]

    def weak_benchmark(self, config: BenchmarkConfig, clean: Path, rate: float) -> SceneBenchmark:
        """The weak copy of `clean` at `rate` (made once) and its benchmark."""
        name = self.weak_name(clean, rate)
        weak = config.output / "weak" / name
        if not (weak / "transforms.json").is_file():
            make_weak_dataset(clean, weak, REGISTRY[self.target], rate, self.mode, self.seed)
        return SceneBenchmark(config, weak, name)

    def weak_name(self, clean: Path, rate: float) -> str:
        suffix = f"-{self.mode}" if REGISTRY[self.target].corruption == "classes" else ""
        return f"{clean.name}-{self.target}-{rate:g}{suffix}"

    def figure(self, clean: Path, config: BenchmarkConfig, spec: PropertySpec) -> Path:
        """Fig. 4, measured: for one training view, per rate the weak label, SS-NeRF's render and the clean label."""
        truth = SSNeRFDataset(SSNeRFDataParserConfig(data=clean).setup().get_dataparser_outputs("train"))
        palette = semantic_palette(truth.num_classes, truth.metadata.get("semantic_colors"))
        index = min(self.figure_view, len(truth) - 1)
        rows = {}
        for rate in self.chosen_rates():
            weak = config.output / "weak" / self.weak_name(clean, rate)
            weak_set = SSNeRFDataset(SSNeRFDataParserConfig(data=weak).setup().get_dataparser_outputs("train"))
            model = SceneBenchmark(config, weak, weak.name).load(single(self.target)).model
            outputs = model.render_camera(truth.cameras[index : index + 1].to(model.device))  # type: ignore
            rows[f"rate {rate:g}"] = {"weak": shown_label(spec, weak_set[index], truth.num_classes, palette),
                                      "render": shown(spec, outputs[spec.prediction_key], palette),
                                      "clean": shown_label(spec, truth[index], truth.num_classes, palette)}
        path = config.output / f"figure_autolabel_{self.target}.png"
        image_grid(path, [("weak", "weak label"), ("render", "SS-NeRF render"), ("clean", "clean label")], rows,
                   f"{clean.name}, training view {index}: {self.target} learnt from weak labels")
        return path

    def score(self, clean: Path, weak: Path, bench: SceneBenchmark, run: ModelRun,
              spec: PropertySpec) -> Dict[str, Any]:
        """The property's headline metric of the weak labels and of the renders, against clean labels (cached)."""
        cache = bench.run_dir(run.name) / "autolabel.json"
        measures = property_columns(spec.name)
        if cache.is_file():
            cached = json.loads(cache.read_text())
            if all(f"{COLUMNS[0]}{suffix(measure)}" in cached for measure in measures):
                return cached
        model = bench.load(run.name).model
        scores: Dict[str, Any] = {}
        for split, label in (("train", "training views"), ("test", "test views")):
            truth = SSNeRFDataset(SSNeRFDataParserConfig(data=clean).setup().get_dataparser_outputs(split))
            weak_set = SSNeRFDataset(SSNeRFDataParserConfig(data=weak).setup().get_dataparser_outputs(split))
            classes = truth.num_classes

            def weak_labels(cameras, index, weak_set=weak_set, classes=classes):
                return {spec.name: spec.kind.label_as_prediction(spec.label(weak_set[index], classes), classes)}

            def rendered(cameras, index):
                outputs = model.render_camera(cameras[index : index + 1].to(model.device))  # type: ignore
                return {spec.name: outputs[spec.prediction_key].cpu()}

            CONSOLE.print(f"[dim]{weak.name}: scoring weak labels and renders on the clean {label}")
            weak_scores = score_predictor(weak_labels, truth, [spec], classes)
            render_scores = score_predictor(rendered, truth, [spec], classes)
            for measure in measures:
                scores[f"weak labels, {label}{suffix(measure)}"] = weak_scores[measure.metric]
                scores[f"SS-NeRF, {label}{suffix(measure)}"] = render_scores[measure.metric]
        write_text_atomic(cache, json.dumps(scores, indent=2))
        return scores

    def tables(self, results: Results) -> Tuple[str, Dict[str, Any]]:
        texts, tables = [], {}
        for index, measure in enumerate(property_columns(self.target)):
            rows = []
            for rate in (f"{rate:g}" for rate in self.chosen_rates()):
                for scene, by_rate in [*results.items(), ("average", None)]:
                    row: Dict[str, Any] = {"row": f"rate {rate} ({scene})"}
                    for column in COLUMNS:
                        key = column + suffix(measure)
                        values = [by_rate[rate].get(key)] if by_rate else [r[rate].get(key) for r in results.values()]
                        row[column] = average(values)
                    rows.append(row)
            tables["autolabel" if index == 0 else f"autolabel_{measure.metric}"] = rows
            texts.append(f"{measure.title} against the clean labels; weak labels: "
                         f"{REGISTRY[self.target].corruption} corruption"
                         + (f" ({self.mode})" if REGISTRY[self.target].corruption == "classes" else "") + "\n\n"
                         + markdown(rows, list(COLUMNS), list(COLUMNS), 4))
        return "\n\n".join(texts), {**tables, "target": self.target, "rates": list(self.chosen_rates())}
