"""`ssnerf-study augmentation`: SS-NeRF's renders as training data for a task network (the paper's Table 6).

Per property, a task network (the Hybrid baseline's encoder-decoder) maps RGB to the property, trained on all scenes'
training views pooled (as the paper does) under four data settings: GT (real images and labels), SS-NeRF (renders at
the training poses), GT + SS-NeRF (both) and GT + SS-NeRF-N (real data and renders at poses between adjacent training
poses). Every network gets the same steps, so the settings differ in data only; each is scored on the test views.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, List, Tuple

import numpy as np
import torch

from nerfstudio.utils.rich_utils import CONSOLE

from ssnerf_method.atomic import save_torch_atomic, write_text_atomic
from ssnerf_method.data.dataparser import SSNeRFDataParserConfig
from ssnerf_method.data.dataset import SSNeRFDataset
from ssnerf_method.errors import UserError
from ssnerf_method.evaluation.figures import image_grid, shown, shown_label
from ssnerf_method.evaluation.hybrid import HybridBaseline, HybridBaselineConfig
from ssnerf_method.evaluation.scoring import score_predictor
from ssnerf_method.experiments.benchmark import ModelRun, SceneBenchmark, generated_scenes, run_tag
from ssnerf_method.experiments.launcher import launch
from ssnerf_method.experiments.report import average, columns_of, property_columns, property_table
from ssnerf_method.experiments.studies import RUN_RECORD, Results, StudyConfig, single, write_study_report
from ssnerf_method.export.dataset import ExportDatasetConfig, export_dataset
from ssnerf_method.properties import OPTIONAL_PROPERTIES, REGISTRY, PropertyName
from ssnerf_method.rendering.palette import semantic_palette

SETTINGS: Dict[str, Tuple[str, ...]] = {
    "GT": ("ground truth",),
    "SS-NeRF": ("training poses",),
    "GT + SS-NeRF": ("ground truth", "training poses"),
    "GT + SS-NeRF-N": ("ground truth", "novel poses"),
}
"""The paper's data settings: which training sets each pools."""
RENDERS = {"training poses": 0, "novel poses": 1}
"""Rendered training sets: poses inserted between adjacent training poses (0: the training poses themselves)."""


def load_split(root: Path, split: str) -> SSNeRFDataset:
    return SSNeRFDataset(SSNeRFDataParserConfig(data=root).setup().get_dataparser_outputs(split))


@dataclass
class AugmentationStudy(StudyConfig):
    """Table 6: a task network per property trained on ground truth, SS-NeRF renders, or both."""

    properties: Tuple[PropertyName, ...] = OPTIONAL_PROPERTIES
    """Properties with a task network."""
    task_network: HybridBaselineConfig = field(default_factory=HybridBaselineConfig)
    """Size and schedule of every task network (the Hybrid baseline's defaults)."""
    figure_view: int = 0
    """Test view of the first scene shown in the figure."""

    name = "augmentation"
    scope = ("Task networks trained on the training data of all scenes together; metrics on each scene's test views "
             "(real RGB in), computed as `ns-eval` does, then averaged over the scenes.")

    def runs(self) -> List[ModelRun]:
        return [ModelRun(single(prop), (prop,)) for prop in self.properties]

    def network_config(self) -> HybridBaselineConfig:
        return HybridBaselineConfig(width=8, depth=3, steps=30, batch_size=4) if self.quick else self.task_network

    def run(self) -> Results:
        """SS-NeRF per property and scene (reused), its renders, then four task networks per property."""
        start = time.time()
        config = self.benchmark_config()
        config.output.mkdir(parents=True, exist_ok=True)
        scenes = list(config.scenes) or generated_scenes(config)
        # renders and task networks come from SS-NeRF runs of one method and schedule
        folder = config.output / "augmentation" / config.method / run_tag(config)
        data: Dict[str, Dict[str, List[SSNeRFDataset]]] = {prop: {} for prop in self.properties}
        tests = {scene.name: load_split(scene, "test") for scene in scenes}
        details: Dict[str, Any] = {}
        launch(config, self.jobs(config, scenes))
        for scene in scenes:
            bench = SceneBenchmark(config, scene, scene.name)
            ground_truth = load_split(scene, "train")
            details[scene.name] = {}
            for prop in self.properties:
                run = ModelRun(single(prop), (prop,))
                CONSOLE.print(f"[bold]augmentation study, {scene.name}: {run.name} and its renders")
                metrics = bench.train_and_score(run)
                if "failed" in metrics:  # its renders, and so the task networks, cannot be made
                    raise UserError(f"{scene.name}/{run.name} failed ({metrics['failed']['error']}), log "
                                    f"{metrics['failed']['log']}: run the study again to retry it (finished runs "
                                    "are kept)")
                record = {key: metrics.get(key) for key in RUN_RECORD}
                details[scene.name][run.name] = {"properties": [prop], **record}
                data[prop].setdefault("ground truth", []).append(ground_truth)
                for poses, between in RENDERS.items():
                    root = folder / "renders" / scene.name / f"{prop}-{poses.replace(' ', '-')}"
                    if not (root / "transforms.json").is_file():
                        export_dataset(ExportDatasetConfig(
                            load_config=bench.config_path(run.name), output_dir=root, split="train", between=between,
                            include_split_poses=between == 0, depth=False, test_every=0, overwrite=True))
                    data[prop].setdefault(poses, []).append(load_split(root, "train"))

        results: Results = {scene: {} for scene in tests}
        figure_rows: Dict[str, Dict[str, np.ndarray]] = {}
        first = next(iter(tests.values()))
        index = min(self.figure_view, len(first) - 1)
        palette = semantic_palette(first.num_classes, first.metadata.get("semantic_colors"))
        networks: Dict[str, Any] = {}
        for prop in self.properties:
            spec = REGISTRY[prop]
            truth = shown_label(spec, first[index], first.num_classes, palette)
            figure_rows.setdefault("ground truth", {})[prop] = truth
            for setting, sources in SETTINGS.items():
                training = [dataset for source in sources for dataset in data[prop][source]]
                network, history = self.task_network_for(folder, prop, setting, training)
                for scene, test in tests.items():
                    def predict(cameras, i, test=test, network=network):  # real test RGB in
                        return network.predict_image(test[i]["image"])

                    scores = score_predictor(predict, test, [spec], test.num_classes)
                    results[scene].setdefault(setting, {}).update(
                        {column.key: scores[column.metric] for column in property_columns(prop)})
                prediction = network.predict_image(first[index]["image"])[prop]
                figure_rows.setdefault(setting, {})[prop] = shown(spec, prediction, palette)
                networks[f"{prop}: {setting}"] = {"training_images": len(network.images), **history}
        rgb_spec = REGISTRY["rgb"]
        rgb = shown_label(rgb_spec, first[index], first.num_classes, palette)
        for row in figure_rows.values():
            row["rgb"] = rgb
        columns = [(rgb_spec.name, f"{rgb_spec.short} (input)"),
                   *((prop, REGISTRY[prop].short) for prop in self.properties)]
        image_grid(config.output / "figure_augmentation.png", columns, figure_rows,
                   f"{next(iter(tests))}, test view {index}: task-network predictions per data setting")
        write_study_report(self, results, {"ssnerf_runs": details, "task_networks": networks}, time.time() - start)
        return results

    def task_network_for(self, folder: Path, prop: str, setting: str,
                         training: List[SSNeRFDataset]) -> Tuple[HybridBaseline, Dict[str, Any]]:
        """The task network of `prop` under `setting`, trained on `training` once and kept in a .pt file."""
        network = HybridBaseline(training, [REGISTRY[prop]], training[0].num_classes, self.network_config())
        weights = folder / "networks" / f"{prop}-{setting.replace(' + ', '+').replace(' ', '-')}.pt"
        log = weights.with_suffix(".json")
        if weights.is_file() and log.is_file():
            network.networks.load_state_dict(torch.load(weights))
            return network, json.loads(log.read_text())
        CONSOLE.print(f"[bold]augmentation study: {prop} task network, {setting} ({len(network.images)} images)")
        losses = network.fit()[prop]
        history = {"first_loss": float(np.mean(losses[:10])), "last_loss": float(np.mean(losses[-10:])),
                   "steps": len(losses)}
        weights.parent.mkdir(parents=True, exist_ok=True)
        save_torch_atomic(network.networks.state_dict(), weights)
        write_text_atomic(log, json.dumps(history, indent=2))  # last: its presence says the weights are whole
        return network, history

    def tables(self, results: Results) -> Tuple[str, Dict[str, Any]]:
        keys = [column.key for column in columns_of(self.properties)]
        rows = [{"row": setting, **{key: average([runs[setting].get(key) for runs in results.values()])
                                    for key in keys}} for setting in SETTINGS]
        per_scene = [{"row": f"{setting} ({scene})", **{key: runs[setting].get(key) for key in keys}}
                     for scene, runs in results.items() for setting in SETTINGS]
        text = (property_table(rows, self.properties) + "\n\nPer scene\n\n" + property_table(per_scene, self.properties)
                + "\n\nFigure: `figure_augmentation.png`")
        return text, {"table6": rows, "per_scene": per_scene,
                      "task_network": vars(self.network_config())}
