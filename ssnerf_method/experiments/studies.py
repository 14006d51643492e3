"""`ssnerf-study`: the paper's ablation and multi-task studies (Sec. 4.3), one command each.

Each study trains its models on every scene as the benchmark does and writes `study_<name>.md` and `.json`. Runs are
named by what they train, so a study reuses the runs the benchmark or another study left in the same output folder.

- `branches` (Table 3): each property on F_dec^v and on F_dec^nv; world-frame against pose-conditioned normals.
- `rgb` (Table 2): RGB PSNR with and without each property; each property with and without the RGB loss.
- `multitask` (Table 4): a target property alone, with each other property, and with all; (+)/(-) against alone.
- `class-grid` (this plugin's option): each property with and without the coarse class grid as a decoder input.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Callable, Dict, List, Optional, Tuple

from nerfstudio.utils.rich_utils import CONSOLE

from ssnerf_method.atomic import write_text_atomic
from ssnerf_method.experiments.benchmark import (
    ALL,
    DEFAULT_STEPS,
    NERF,
    BenchmarkConfig,
    ModelRun,
    SceneBenchmark,
    ScenesRunsConfig,
    generated_scenes,
    quick_config,
)
from ssnerf_method.experiments.launcher import Job, launch
from ssnerf_method.experiments.report import (
    Column,
    average,
    cell,
    columns_of,
    failures,
    headline,
    markdown,
    property_columns,
    property_table,
    property_title,
    training_words,
)
from ssnerf_method.method_configs import ssnerf_lite_config
from ssnerf_method.model.ssnerf_model import CLASS_GRID_PROPERTIES
from ssnerf_method.properties import OPTIONAL_PROPERTIES, REGISTRY, PropertyName

Results = Dict[str, Dict[str, Dict[str, Any]]]
"""scene -> run name -> that run's test-split metrics."""
RUN_RECORD = ("train_seconds", "seed", "config")
LITE_MODEL = ssnerf_lite_config.pipeline.model
"""`ssnerf-lite`'s model config, whose class-grid settings the class-grid study starts from."""


def single(name: str) -> str:
    """Run name of the default single-property SS-NeRF (the benchmark's)."""
    return f"ssnerf-{name}"


def together(names: Tuple[str, ...]) -> str:
    """Run name of a model trained on `names` (registry order, so the same set always has the same name)."""
    ordered = [name for name in OPTIONAL_PROPERTIES if name in names]
    if ordered == list(OPTIONAL_PROPERTIES):
        return ALL
    return single(ordered[0]) if len(ordered) == 1 else "ssnerf-" + "+".join(ordered)


def scene_rows(results: Results, title: str, properties: Tuple[str, ...], run_of: Callable[[str], str]
               ) -> List[Dict[str, Any]]:
    """Rows `title (scene)` per scene and their average, each property's columns read from `run_of(property)`."""
    rows = []
    for scene, runs in [*results.items(), ("average", None)]:
        row: Dict[str, Any] = {"row": f"{title} ({scene})"}
        for column in columns_of(properties):
            row[column.key] = average([r.get(run_of(column.prop), {}).get(column.metric)
                                       for r in (results.values() if runs is None else [runs])])
        rows.append(row)
    return rows


@dataclass
class StudyConfig(ScenesRunsConfig):
    """What every study shares: scenes, architecture, output folder, steps and --quick."""

    name = "study"
    scope = "Metrics on each scene's test split, as `ns-eval` computes them."

    def runs(self) -> List[ModelRun]:
        raise NotImplementedError

    def jobs(self, config: BenchmarkConfig, scenes: List[Path]) -> List[Job]:
        """The study's trainings as launcher jobs (`--launcher ray` runs them before the report is written)."""
        return [SceneBenchmark(config, scene, scene.name).job(run) for scene in scenes for run in self.runs()]

    def run(self) -> Results:
        return run_study(self)

    def tables(self, results: Results) -> Tuple[str, Dict[str, Any]]:
        """The study's Markdown tables and their JSON."""
        raise NotImplementedError

    def benchmark_config(self) -> BenchmarkConfig:
        """The benchmark's settings for this study's runs: every shared option, --launcher and its Ray flags too."""
        config = BenchmarkConfig(**{option.name: getattr(self, option.name) for option in fields(ScenesRunsConfig)})
        return quick_config(config) if self.quick else config


@dataclass
class BranchStudy(StudyConfig):
    """Table 3: each property on the view-dependent decoder F_dec^v and on the view-independent F_dec^nv."""

    properties: Tuple[PropertyName, ...] = ("semantics", "shading", "keypoints", "edges")
    """Properties moved between the branches."""
    normals: bool = True
    """Also compare normals in this plugin's world-frame mode with the paper's pose-conditioned mode."""

    name = "branches"

    def run_on(self, prop: str, branch: str) -> ModelRun:
        if branch == REGISTRY[prop].branch:
            return ModelRun(single(prop), (prop,))
        return ModelRun(f"{single(prop)}-on-{branch}", (prop,), {"branches": {prop: branch}})

    def runs(self) -> List[ModelRun]:
        runs = [self.run_on(prop, branch) for prop in self.properties for branch in ("v", "nv")]
        if self.normals:
            runs += [ModelRun(single("normals"), ("normals",)),
                     ModelRun("ssnerf-normals-pose", ("normals",), {"normals_mode": "pose"})]
        return runs

    def tables(self, results: Results) -> Tuple[str, Dict[str, Any]]:
        rows = [row for branch, title in (("v", "F_dec^v"), ("nv", "F_dec^nv"))
                for row in scene_rows(results, title, self.properties,
                                      lambda prop, branch=branch: self.run_on(prop, branch).name)]
        text = property_table(rows, self.properties)
        data: Dict[str, Any] = {"table3": rows}
        if self.normals:
            key = headline("normals")[0]
            normal_rows = [{"row": title, **{scene: runs.get(run, {}).get(key) for scene, runs in results.items()},
                            "average": average([runs.get(run, {}).get(key) for runs in results.values()])}
                           for title, run in (("world-frame normals on F_dec^nv (this plugin's default)",
                                               single("normals")),
                                              ("pose-conditioned normals (the paper's)", "ssnerf-normals-pose"))]
            columns = [*results, "average"]
            text += f"\n\n{property_title('normals')}\n\n" + markdown(normal_rows, columns, columns, 4)
            data["normals"] = normal_rows
        return text, data


@dataclass
class RGBStudy(StudyConfig):
    """Table 2: RGB PSNR with and without each property (left); each property with and without RGB (right)."""

    properties: Tuple[PropertyName, ...] = OPTIONAL_PROPERTIES

    name = "rgb"

    def runs(self) -> List[ModelRun]:
        return [ModelRun(NERF, ()), *(ModelRun(single(prop), (prop,)) for prop in self.properties),
                *(ModelRun(f"{single(prop)}-no-rgb", (prop,), {"loss_weights": {"rgb": 0.0}})
                  for prop in self.properties)]

    def tables(self, results: Results) -> Tuple[str, Dict[str, Any]]:
        left_columns = [NERF, *(single(prop) for prop in self.properties)]
        left = [{"row": scene, **{run: runs.get(run, {}).get("psnr") for run in left_columns}}
                for scene, runs in results.items()]
        left.append({"row": "average", **{run: average([row[run] for row in left]) for run in left_columns}})
        with_rgb, without = (scene_rows(results, title, self.properties,
                                        lambda prop, suffix=suffix: single(prop) + suffix)
                             for suffix, title in (("", "with RGB"), ("-no-rgb", "without RGB")))
        right = [row for pair in zip(with_rgb, without) for row in pair]  # per scene: with, then without
        titles = ["NeRF", *(f"SS-NeRF-{REGISTRY[prop].short}" for prop in self.properties)]
        text = ("Left: RGB PSNR\n\n" + markdown(left, left_columns, titles, 2)
                + "\n\nRight: each property with and without the RGB loss\n\n"
                + property_table(right, self.properties))
        return text, {"table2_left": left, "table2_right": right}


@dataclass
class MultiTaskStudy(StudyConfig):
    """Table 4: a target property alone, with each other property, and with all of them."""

    target: PropertyName = "shading"
    """The property scored (the paper's Table 4 uses SH)."""
    others: Tuple[PropertyName, ...] = OPTIONAL_PROPERTIES
    """Properties paired with the target (the target itself is skipped)."""

    name = "multitask"

    def partners(self) -> List[str]:
        return [prop for prop in self.others if prop != self.target]

    def columns(self) -> Dict[str, ModelRun]:
        columns = {"alone": ModelRun(single(self.target), (self.target,))}
        for prop in self.partners():
            pair = (self.target, prop)
            columns[f"+{REGISTRY[prop].short}"] = ModelRun(together(pair), pair)
        everything = (self.target, *self.partners())
        columns["all"] = ModelRun(together(everything), everything)
        return columns

    def runs(self) -> List[ModelRun]:
        return list(self.columns().values())

    def tables(self, results: Results) -> Tuple[str, Dict[str, Any]]:
        texts, data = [], {}
        for index, column in enumerate(property_columns(self.target)):
            text, rows = self.table(results, column)
            texts.append(text)
            data["table4" if index == 0 else f"table4_{column.metric}"] = rows
        key, higher = headline(self.target)
        return "\n\n".join(texts), {**data, "target": self.target, "metric": key, "higher_is_better": higher}

    def table(self, results: Results, column: Column) -> Tuple[str, List[Dict[str, Any]]]:
        """Table 4 for one measure of the target: rows and Markdown, cells marked (+)/(−) against it alone."""
        columns = self.columns()
        rows = []
        for scene, runs in results.items():
            row: Dict[str, Any] = {"row": scene}
            row.update({title: runs.get(run.name, {}).get(column.metric) for title, run in columns.items()})
            rows.append(row)
        rows.append({"row": "average", **{title: average([row[title] for row in rows]) for title in columns}})
        marked = []
        for row in rows:
            alone = row["alone"]
            cells: Dict[str, Any] = {"row": row["row"]}
            for title in columns:
                value = row[title]
                mark = ""
                if title != "alone" and value is not None and alone is not None and value != alone:
                    mark = " (+)" if (value > alone) == column.higher else " (−)"
                cells[title] = cell(value, 4) + mark
            marked.append(cells)
        lines = ["| | " + " | ".join(columns) + " |", "|---|" + "---|" * len(columns)]
        lines += ["| " + cells["row"] + " | " + " | ".join(cells[title] for title in columns) + " |"
                  for cells in marked]
        return f"{column.title}; (+) better, (−) worse than the target alone\n\n" + "\n".join(lines), rows


@dataclass
class ClassGridStudy(StudyConfig):
    """Which decoders should read the class grid: each property with and without it, and the all-properties model."""

    properties: Tuple[PropertyName, ...] = OPTIONAL_PROPERTIES
    """Properties compared with and without the grid, each in a model of its own."""
    gridded: Tuple[PropertyName, ...] = LITE_MODEL.class_grid_properties
    """The all-properties model's second setting: the properties whose decoders read the grid (ssnerf-lite's)."""
    max_res: int = LITE_MODEL.class_grid_max_res
    """Finest resolution of the class grid, set in every run so that `ssnerf` gets the grid too."""
    all_properties_model: bool = True
    """Also compare the all-properties model with the grid for the class property only and for `--gridded`."""

    name = "class-grid"

    def alone(self, prop: str, grid: bool) -> ModelRun:
        """`prop` alone, its decoder reading the grid or not (no other decoder exists to read it)."""
        return ModelRun(f"{single(prop)}-{'' if grid else 'no-'}class-grid", (prop,),
                        {"class_grid_max_res": self.max_res, "class_grid_properties": (prop,) if grid else ()})

    def everything(self, gridded: Tuple[str, ...]) -> ModelRun:
        ordered = tuple(name for name in OPTIONAL_PROPERTIES if name in gridded)
        return ModelRun(f"{ALL}-class-grid-" + "+".join(ordered), OPTIONAL_PROPERTIES,
                        {"class_grid_max_res": self.max_res, "class_grid_properties": ordered})

    def settings(self) -> Dict[str, Tuple[str, ...]]:
        """The all-properties model's two settings: row title -> the properties given the grid."""
        return {f"all properties, grid for {', '.join(gridded)}": gridded
                for gridded in (CLASS_GRID_PROPERTIES, self.gridded)}

    def runs(self) -> List[ModelRun]:
        runs = [self.alone(prop, grid) for prop in self.properties for grid in (False, True)]
        if self.all_properties_model:
            runs += [self.everything(gridded) for gridded in self.settings().values()]
        return runs

    def tables(self, results: Results) -> Tuple[str, Dict[str, Any]]:
        rows = [row for grid, title in ((False, "alone, no class grid"), (True, "alone, with the class grid"))
                for row in scene_rows(results, title, self.properties,
                                      lambda prop, grid=grid: self.alone(prop, grid).name)]
        text = "Each property in a model of its own\n\n" + property_table(rows, self.properties)
        data: Dict[str, Any] = {"alone": rows}
        if self.all_properties_model:
            columns = [("psnr", "RGB PSNR ↑"), *((column.metric, column.title)
                                                 for column in columns_of(OPTIONAL_PROPERTIES))]
            every = [{"row": title, **{metric: average([runs.get(self.everything(gridded).name, {}).get(metric)
                                                        for runs in results.values()]) for metric, _ in columns}}
                     for title, gridded in self.settings().items()]
            text += ("\n\nThe all-properties model, averaged over the scenes\n\n"
                     + markdown(every, [metric for metric, _ in columns], [title for _, title in columns], 4))
            data["all"] = every
        return text, data


def commit() -> Optional[str]:
    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], cwd=Path(__file__).parent, capture_output=True,
                              text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None


def run_study(study: StudyConfig) -> Results:
    """Train (or reuse) every run of `study` on every scene and write its report; returns the per-scene results."""
    start = time.time()
    config = study.benchmark_config()
    config.output.mkdir(parents=True, exist_ok=True)
    scenes = list(config.scenes) or generated_scenes(config)
    runs = study.runs()
    launch(config, study.jobs(config, scenes))
    results: Results = {}
    for scene in scenes:
        bench = SceneBenchmark(config, scene, scene.name)
        results[scene.name] = {}
        for number, run in enumerate(runs, start=1):
            CONSOLE.print(f"[bold]{study.name} study, {scene.name}: model {number}/{len(runs)}: {run.name}")
            results[scene.name][run.name] = bench.train_and_score(run)
    details = {scene: {run.name: {"properties": list(run.properties), "overrides": run.overrides,
                                  **{key: results[scene][run.name].get(key) for key in RUN_RECORD}} for run in runs}
               for scene in results}
    write_study_report(study, results, details, time.time() - start)
    return results


def write_study_report(study: StudyConfig, results: Results, runs: Dict[str, Any], seconds: float) -> Path:
    """Write `study_<name>.md` and `.json`: the tables, command, commit, method, steps and `runs` (per-run records)."""
    config = study.benchmark_config()
    text, tables = study.tables(results)
    steps = config.steps or DEFAULT_STEPS[config.method]
    details = {
        "command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]), "commit": commit(), "method": config.method,
        "steps": steps, "lr_drop": config.lr_drop, "quick": config.quick, "wall_clock_seconds": round(seconds, 1),
        "runs": runs,
    }
    report = "\n\n".join(part for part in [
        f"# SS-NeRF {study.name} study ({training_words(config.method, steps, config.lr_drop)}"
        f"{', --quick' if config.quick else ''})",
        f"Scenes: {', '.join(results)}. {study.scope}",
        text,
        failures(results),
        f"Command: `{details['command']}`; commit {details['commit']}; {details['wall_clock_seconds']} s in all; "
        f"per-run training time and seed in `study_{study.name}.json`.",
    ] if part)
    path = config.output / f"study_{study.name}.md"
    write_text_atomic(path, report + "\n")
    write_text_atomic(config.output / f"study_{study.name}.json",
                      json.dumps({**details, "tables": tables, "results": results}, indent=2))
    CONSOLE.print(report)
    return path
