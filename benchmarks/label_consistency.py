"""How far a dataset's labels agree between its training views.

    python -m benchmarks.label_consistency DATA [--properties keypoints edges] [--every 4] \
        [--output consistency.json]

Each scored training view's labels are compared with the labels of its nearest other training views, warped into it
with the depth maps (the Heuristic baseline, `evaluation/heuristic.py`, with the view itself left out), and scored
with the benchmark's metrics. A field renders one answer per surface point (and what the view direction explains), so
labels that change from one view to the next, such as a detector's response that depends on the distance it was
computed at, bound what it can learn. Needs depth maps (`depth_file_path`).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, Optional, Tuple

import tyro
from rich.table import Table

from nerfstudio.utils.rich_utils import CONSOLE

from ssnerf_method.data.dataparser import SSNeRFDataParserConfig
from ssnerf_method.data.dataset import SSNeRFDataset
from ssnerf_method.data.io import write_json_atomic
from ssnerf_method.evaluation.heuristic import HeuristicBaseline
from ssnerf_method.metrics import METRICS, Statistics, add_statistics, summarize
from ssnerf_method.properties import OPTIONAL_PROPERTIES, PropertyName, resolve_properties


@dataclass
class LabelConsistencyConfig:
    """Score each training view's labels against its neighbours' labels warped into it with depth."""

    data: tyro.conf.Positional[Path]
    """Dataset folder (transforms.json with depth maps and labels)."""
    properties: Tuple[PropertyName, ...] = OPTIONAL_PROPERTIES
    """Properties to score (those the dataset labels)."""
    every: int = 1
    """Score every n-th training view (all of them warp into it)."""
    output: Optional[Path] = None
    """Also write the scores to this JSON file."""


def label_consistency(config: LabelConsistencyConfig) -> Dict[str, float]:
    """The metrics (`metrics.METRICS`, split-level) of the training views' labels against their neighbours'."""
    parser = SSNeRFDataParserConfig(data=config.data).setup()
    train = SSNeRFDataset(parser.get_dataparser_outputs("train"))
    if train.depth_files is None:
        raise ValueError(f"{config.data / 'transforms.json'}: no depth maps; label consistency warps labels with "
                         "depth: give the frames a depth_file_path (e.g. from a depth sensor)")
    if config.every < 1:
        raise ValueError(f"--every counts training views; give 1 or more, not {config.every}")
    available = train.metadata.get("available_properties", ())
    specs = [spec for spec in resolve_properties(config.properties) if spec.name in available]
    if not specs:
        raise ValueError(f"{config.data / 'transforms.json'}: none of {', '.join(config.properties)} is labelled; "
                         f"label them with ssnerf-label")
    num_classes = len(train.metadata.get("semantic_classes", []))
    everyone = list(range(len(train)))
    baseline = HeuristicBaseline(train, specs, num_classes, train.metadata["dataparser_scale"])
    totals: Dict[str, Statistics] = {}
    for index in everyone[:: config.every]:
        baseline.sources = [other for other in everyone if other != index]
        predictions = baseline.predict_view(train.cameras, index)
        item = baseline.item(index)
        for spec in specs:
            label = spec.label(item, num_classes)
            view = METRICS[spec.metric].statistics(predictions[spec.name], label, spec.kind.valid(label), num_classes)
            totals[spec.name] = add_statistics(totals.get(spec.name, {}), view)
    return summarize(totals, specs)


def main(config: LabelConsistencyConfig) -> Dict[str, float]:
    scores = label_consistency(config)
    table = Table(title=f"{config.data}: each training view's labels against its neighbours', warped with depth")
    table.add_column("metric")
    table.add_column("value", justify="right")
    for name, value in scores.items():
        table.add_row(name, f"{value:.4f}")
    CONSOLE.print(table)
    if config.output is not None:
        write_json_atomic(config.output, scores)
    return scores


def entrypoint() -> None:
    try:
        main(tyro.cli(LabelConsistencyConfig))
    except ValueError as error:
        CONSOLE.print(f"[bold red]{error}")
        sys.exit(1)


if __name__ == "__main__":
    entrypoint()
