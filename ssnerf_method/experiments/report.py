"""The benchmark's report: the paper's Table 1 and Table 2-left as Markdown and JSON, from per-scene results."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

from ssnerf_method.atomic import write_text_atomic
from ssnerf_method.data.spacing import ANGLE_WEIGHT
from ssnerf_method.metrics import METRICS
from ssnerf_method.properties import REGISTRY

Results = Dict[str, Dict[str, Dict[str, float]]]
"""scene -> row (run name, "heuristic", "hybrid", "nearest") -> metric name -> value."""
BASELINE_ROWS = {"heuristic": "Heuristic", "hybrid": "Hybrid", "nearest": "Nearest training view copied"}
"""Table 1's rows that train no field (benchmark.BASELINES), by result key, as the report names them."""


@dataclass(frozen=True)
class Column:
    """One reported number of a property: a column of Table 1 and of the studies' property tables."""

    key: str
    """Row key in the JSON tables: the property's name for its headline (the paper's number), else the metric."""
    prop: str
    metric: str
    """Metric name in the runs' metrics (`semantics_miou`, `edges_f1`, ...)."""
    higher: bool
    decides: bool = True
    """Whether a comparison between methods reads it (`Metric.decides`): F1 and AP for the sparse maps, not L1."""

    @property
    def measure(self) -> str:
        """The metric's name without the property's prefix (`f1` of `edges_f1`)."""
        return self.metric[len(REGISTRY[self.prop].metric_prefix):]

    @property
    def title(self) -> str:
        """The paper's abbreviation, the measure and the better direction, e.g. `ED f1 ↑`."""
        return f"{REGISTRY[self.prop].short} {self.measure} " + ("↑" if self.higher else "↓")


def property_columns(name: str) -> List[Column]:
    """A property's reported numbers: the paper's headline first, then the others (e.g. F1 and AP for sparse maps)."""
    spec, metric = REGISTRY[name], METRICS[REGISTRY[name].metric]
    deciding = metric.decides or (metric.reported[0][0],)
    return [Column(name if index == 0 else spec.metric_prefix + key, name, spec.metric_prefix + key, higher,
                   key in deciding) for index, (key, higher) in enumerate(metric.reported)]


def columns_of(properties: Sequence[str]) -> List[Column]:
    return [column for name in properties for column in property_columns(name)]


def headline(name: str) -> Tuple[str, bool]:
    """Metric name of a property's Table 1 number (`semantics_miou`, `normals_l1`, ...) and if higher is better."""
    first = property_columns(name)[0]
    return first.metric, first.higher


def property_title(name: str) -> str:
    return property_columns(name)[0].title


def average(values: Sequence[Optional[float]]) -> Optional[float]:
    kept = [value for value in values if value is not None and not math.isnan(value)]
    return sum(kept) / len(kept) if kept else None


def table1(results: Results, properties: Sequence[str]) -> List[Dict]:
    """Rows of Table 1: SS-NeRF per scene and averaged, then the all-properties model's and baselines' averages."""
    columns = columns_of(properties)
    rows = []
    for scene, runs in results.items():
        rows.append({"row": f"SS-NeRF ({scene})", **{
            column.key: runs.get(f"ssnerf-{column.prop}", {}).get(column.metric) for column in columns}})
    rows.append({"row": "SS-NeRF, average", **{column.key: average([row[column.key] for row in rows])
                                               for column in columns}})
    for label, run in (("SS-NeRF, one model for all properties, average", "ssnerf-all"),
                       *((f"{title}, average", key) for key, title in BASELINE_ROWS.items())):
        if any(run in runs for runs in results.values()):
            rows.append({"row": label, **{column.key: average([runs.get(run, {}).get(column.metric)
                                                               for runs in results.values()]) for column in columns}})
    return rows


def table2(results: Results, properties: Sequence[str]) -> List[Dict]:
    """Rows of Table 2-left: RGB PSNR of the NeRF and of each single-property SS-NeRF, per scene and averaged."""
    columns = ["nerf", *(f"ssnerf-{name}" for name in properties)]
    rows = [{"row": scene, **{column: runs.get(column, {}).get("psnr") for column in columns}}
            for scene, runs in results.items()]
    rows.append({"row": "average", **{column: average([row[column] for row in rows]) for column in columns}})
    return rows


def cell(value: Optional[float], digits: int) -> str:
    return "–" if value is None or math.isnan(value) else f"{value:.{digits}f}"


def markdown(rows: List[Dict], columns: Sequence[str], titles: Sequence[str], digits: int) -> str:
    lines = ["| | " + " | ".join(titles) + " |", "|---|" + "---|" * len(titles)]
    lines += ["| " + row["row"] + " | " + " | ".join(cell(row[column], digits) for column in columns) + " |"
              for row in rows]
    return "\n".join(lines)


def property_table(rows: List[Dict], properties: Sequence[str], digits: int = 4) -> str:
    """Markdown of rows keyed by `columns_of(properties)`, titled by the columns."""
    columns = columns_of(properties)
    return markdown(rows, [column.key for column in columns], [column.title for column in columns], digits)


def beats(rows: List[Dict], properties: Sequence[str], baseline: str) -> Dict[str, List[str]]:
    """Per property, the deciding measures on which SS-NeRF's average does not beat the baseline's (empty: a win)."""
    ours = next(row for row in rows if row["row"] == "SS-NeRF, average")
    theirs = next((row for row in rows if row["row"] == f"{baseline}, average"), None)
    result = {}
    for name in properties:
        deciding = [column for column in property_columns(name) if column.decides]
        if theirs is None or any(ours.get(c.key) is None or theirs.get(c.key) is None for c in deciding):
            continue
        result[name] = [column.measure for column in deciding if not (
            ours[column.key] > theirs[column.key] if column.higher else ours[column.key] < theirs[column.key])]
    return result


def training_words(method: str, steps: int, lr_drop: Optional[float] = None) -> str:
    """How every model was trained, for a report's title."""
    drop = f", learning rates x0.1 after {lr_drop:.0%} of them" if lr_drop is not None else ""
    return f"{method}, {steps} steps per model{drop}"


def failures(results: Dict[str, Dict[str, Dict]]) -> str:
    """A report's section listing the runs a Ray launch could not finish (error and log), or "" if none."""
    lines = [f"- {scene} / {run}: {metrics['failed']['error']}; log `{metrics['failed']['log']}`"
             for scene, runs in results.items() for run, metrics in runs.items()
             if isinstance(metrics, dict) and "failed" in metrics]
    return "## Failed runs (their cells are empty; run the command again to retry them)\n\n" + "\n".join(lines) \
        if lines else ""


def spacing_table(spacing: Dict[str, Dict]) -> str:
    """Per scene, the median distance and angle from a test view to its nearest training view (and the loop's)."""
    lines = ["| scene | test views | median distance to the nearest training view | median angle | "
             "the loop scene of the same seed |", "|---|---|---|---|---|"]
    def where(values: Optional[Dict]) -> Tuple[str, str]:
        if not values or values.get("median_m") is None:
            return "–", "–"
        return f"{values['median_m']:.2f} m", f"{values['median_deg']:.1f}°"

    for scene, values in spacing.items():
        distance, angle = where(values)
        loop = ", ".join(where(values.get("loop"))) if values.get("loop") else "–"
        lines.append(f"| {scene} | {values['test_views']} | {distance} | {angle} | {loop} |")
    return "\n".join(lines)


def write_report(output: Path, results: Results, properties: Sequence[str], method: str, steps: int,
                 lr_drop: Optional[float] = None, spacing: Optional[Dict[str, Dict]] = None) -> Path:
    """Write `report.md` and `tables.json` into `output`; returns the report's path."""
    first = table1(results, properties)
    second = table2(results, properties)
    verdicts = {baseline: beats(first, properties, baseline) for baseline in BASELINE_ROWS.values()}
    summary = "; ".join(
        f"beats {baseline} on {sum(not lost for lost in verdict.values())}/{len(verdict)}"
        + (" (not on " + ", ".join(f"{name} ({', '.join(lost)})" for name, lost in verdict.items() if lost) + ")"
           if any(verdict.values()) else "")
        for baseline, verdict in verdicts.items() if verdict
    )
    report = "\n\n".join(part for part in [
        f"# SS-NeRF benchmark ({training_words(method, steps, lr_drop)})",
        f"Scenes: {', '.join(results)}. Metrics on each scene's test split, as `ns-eval` computes them "
        "(mIoU from the accumulated confusion matrix, L1 over all labelled pixels).",
        ("How far the test views are from the training views (nearest by centre distance + "
         f"{ANGLE_WEIGHT:g} m per radian, as the Heuristic ranks them):\n\n" + spacing_table(spacing))
        if spacing else "",
        "## Table 1: scene properties",
        property_table(first, properties),
        f"SS-NeRF (average) {summary}." if summary else "",
        "## Table 2 (left): RGB PSNR of NeRF and of each single-property SS-NeRF",
        markdown(second, ["nerf", *(f"ssnerf-{name}" for name in properties)],
                 ["NeRF", *(f"SS-NeRF-{REGISTRY[name].short}" for name in properties)], 2),
        "Figures: " + ", ".join(f"`figure_{scene}.png`" for scene in results),
        failures(results),
    ] if part)
    path = output / "report.md"
    write_text_atomic(path, report + "\n")
    tables = {"method": method, "steps": steps, "lr_drop": lr_drop, "spacing": spacing, "table1": first,
              "table2_left": second,
              "beats": verdicts, "results": results}
    write_text_atomic(output / "tables.json", json.dumps(tables, indent=2))
    return path
