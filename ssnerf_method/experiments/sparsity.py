"""`ssnerf-study sparsity`: SS-NeRF and Table 1's three baselines per property against the number of training views.

For each k of `--views` it runs Table 1 on k evenly spaced training views of a dense sequence: how densely to capture,
and where warping the nearest view stops being enough.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Dict, List, Tuple

from nerfstudio.utils.rich_utils import CONSOLE

from ssnerf_method.experiments.benchmark import (
    BASELINES,
    BENCHMARK_SCENE,
    BenchmarkConfig,
    SceneBenchmark,
    scene_spacing,
)
from ssnerf_method.experiments.launcher import Job, launch
from ssnerf_method.experiments.report import BASELINE_ROWS, average, cell, columns_of, headline, property_title
from ssnerf_method.experiments.studies import RUN_RECORD, Results, StudyConfig, single, write_study_report
from ssnerf_method.experiments.transfer import limited_scene
from ssnerf_method.properties import OPTIONAL_PROPERTIES, REGISTRY, PropertyName
from ssnerf_method.scene.make_scene import MakeSceneConfig, make_scene

METHODS = {"SS-NeRF": None, **{title: key for key, title in BASELINE_ROWS.items()}}
"""Columns of the study: SS-NeRF (each property from its own model), then Table 1's baselines by result key."""
DENSE_FRAMES = 56
"""Frames of the default dense sequence: every 8th held out leaves 49 training views, enough for k = 48."""


def jobs_of(benches: Dict[str, Tuple[Path, int, SceneBenchmark]]) -> List[Job]:
    return [job for _, _, bench in benches.values() for job in bench.jobs()]


@dataclass
class SparsityStudy(StudyConfig):
    """SS-NeRF and Table 1's baselines per property on k training views of one sequence, for several k."""

    properties: Tuple[PropertyName, ...] = OPTIONAL_PROPERTIES
    """Properties scored (one SS-NeRF each per k)."""
    views: Tuple[int, ...] = (48, 24, 12, 6)
    """Numbers of training views kept (evenly spaced along the sequence); the test views are always the same."""
    seed: int = 0
    """Seed of the generated dense sequence (used when --scenes is not given)."""

    name = "sparsity"
    scope = ("Each row trains on k evenly spaced training views of the sequence; every row is scored on the same "
             "test views, as `ns-eval` computes the metrics.")

    def chosen_views(self) -> Tuple[int, ...]:
        return (6, 3) if self.quick and self.views == SparsityStudy.views else self.views

    def sequences(self, config: BenchmarkConfig) -> List[Path]:
        """The dense sequences: --scenes, or the generated walkthrough of --seed with `DENSE_FRAMES` frames."""
        if config.scenes:
            return list(config.scenes)
        root = config.output / "scenes" / f"walkthrough_dense_seed_{self.seed}"
        if not (root / "transforms.json").is_file():
            size = dict(width=40, height=30, num_frames=10) if self.quick else dict(num_frames=DENSE_FRAMES)
            make_scene(MakeSceneConfig(output_dir=root, seed=self.seed, overwrite=True, path_frames=0,  # type: ignore
                                       **BENCHMARK_SCENE, **size))
        return [root]

    def benchmarks(self, config: BenchmarkConfig) -> Dict[str, Tuple[Path, int, SceneBenchmark]]:
        """Per row name (`<scene>-<k>views`): the sequence, k and the benchmark of its k-view copy (made once)."""
        config = BenchmarkConfig(**{**vars(config), "properties": self.properties, "all_properties_model": False})
        rows = {}
        for scene in self.sequences(config):
            for k in self.chosen_views():
                root = limited_scene(config.output, scene, k)
                rows[root.name] = (scene, k, SceneBenchmark(config, root, root.name))
        return rows

    def jobs(self, config: BenchmarkConfig, scenes: List[Path]) -> List[Job]:
        return jobs_of(self.benchmarks(config))

    def run(self) -> Results:
        start = time.time()
        config = self.benchmark_config()
        config.output.mkdir(parents=True, exist_ok=True)
        benches = self.benchmarks(config)
        launch(config, jobs_of(benches))
        results: Results = {}
        details: Dict[str, Any] = {}
        for name, (scene, k, bench) in benches.items():
            CONSOLE.print(f"[bold]sparsity study: {scene.name} with {k} training views")
            results[name] = bench.run()
            details[name] = {"scene": scene.name, "views": k,  # its spacing is in the tables
                             **{run: {key: metrics.get(key) for key in RUN_RECORD}
                                for run, metrics in results[name].items() if run not in BASELINES}}
        self.figure(results, config.output / "figure_sparsity.png")
        write_study_report(self, results, details, time.time() - start)
        return results

    def value(self, runs: Dict[str, Dict[str, Any]], method: str, prop: str, metric: str) -> Any:
        """A method's number for a property in one k-view row: SS-NeRF's from that property's own model."""
        row = METHODS[method]
        return runs.get(single(prop) if row is None else row, {}).get(metric)

    def tables(self, results: Results) -> Tuple[str, Dict[str, Any]]:
        """Per property: rows k (views), a column per `METHODS` entry (every reported measure in the JSON)."""
        texts, data = [], {}
        by_k = self.by_views(results)
        output = self.benchmark_config().output
        spacings = {name: scene_spacing(output / "limited" / name) for name in results}
        for prop in self.properties:
            rows = []
            for k, names in by_k.items():
                row: Dict[str, Any] = {"row": f"{k} views"}
                for method in METHODS:
                    for column in columns_of([prop]):
                        row[f"{method} {column.key}"] = average(
                            [self.value(results[name], method, prop, column.metric) for name in names])
                row["median distance (m)"] = average([spacings[name]["median_m"] for name in names])
                row["median angle (deg)"] = average([spacings[name]["median_deg"] for name in names])
                rows.append(row)
            data[prop] = rows
            lines = [f"{property_title(prop)}", "",
                     "| training views | " + " | ".join(METHODS) + " | test view to nearest training view |",
                     "|---|" + "---|" * (len(METHODS) + 1)]
            for row in rows:
                cells = [cell(row[f"{method} {prop}"], 4) for method in METHODS]
                where = (f"{row['median distance (m)']:.2f} m, {row['median angle (deg)']:.1f}°"
                         if row["median distance (m)"] is not None else "–")
                lines.append(f"| {row['row']} | " + " | ".join(cells) + f" | {where} |")
            texts.append("\n".join(lines))
        return "\n\n".join(texts) + "\n\nFigure: `figure_sparsity.png`.", {"sparsity": data}

    def by_views(self, results: Results) -> Dict[int, List[str]]:
        """k -> the row names trained on k views (one per sequence), in --views order."""
        rows: Dict[int, List[str]] = {k: [] for k in self.chosen_views()}
        for name in results:
            k = int(name.rsplit("-", 1)[1].removesuffix("views"))
            rows.setdefault(k, []).append(name)
        return rows

    def figure(self, results: Results, path: Path) -> Path:
        """One panel per property: its headline measure against k, a curve per method."""
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        by_k = self.by_views(results)
        views = list(by_k)
        figure, axes = plt.subplots(1, len(self.properties), figsize=(3.2 * len(self.properties), 3.0), squeeze=False)
        for axis, prop in zip(axes[0], self.properties):
            metric, higher = headline(prop)
            for method, style in zip(METHODS, ("o-", "s--", "^:", "d-.")):
                values = [average([self.value(results[name], method, prop, metric) for name in by_k[k]])
                          for k in views]
                axis.plot(views, [float("nan") if value is None else value for value in values], style, label=method)
            axis.set_xscale("log", base=2)
            axis.set_xticks(views, [str(k) for k in views])
            axis.set_xlabel("training views")
            axis.set_title(f"{REGISTRY[prop].short} {metric[len(REGISTRY[prop].metric_prefix):]} "
                           f"({'higher' if higher else 'lower'} is better)", fontsize=9)
        axes[0][0].legend(fontsize=8)
        figure.tight_layout()
        figure.savefig(path, dpi=150)
        plt.close(figure)
        return path
