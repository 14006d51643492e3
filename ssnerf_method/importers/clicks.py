"""Answered clicks (`ssnerf-label --suggest-clicks` writes them, a person fills in each `"class"`) as `Annotations`.

`{"clicks": [{"file_path": ..., "x": int, "y": int, "class": "wall" | null}, ...]}`: a click with a class labels its
one pixel (column x, row y of the frame's image); null leaves it unanswered. Classes must be the dataset's own (the
questions came from a model trained on them). Every click is checked before any frame is labelled.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Any, Dict, Sequence

import numpy as np

from ssnerf_method.data.io import DatasetInputError
from ssnerf_method.importers.annotations import Annotations, FrameIndex, FrameShapes, Shape, mask_rle

UNANSWERED = "unanswered click"
"""How a click left at null is counted among the skipped shapes."""


def is_clicks_file(content: Any) -> bool:
    return isinstance(content, dict) and "clicks" in content


def _integer(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def read_clicks(path: Path, content: Dict, index: FrameIndex, classes: Sequence[str]) -> Annotations:
    """The answered clicks of `content` (read from `path`), each one pixel of its frame in its class."""
    clicks = content["clicks"]
    if not isinstance(clicks, list):
        raise DatasetInputError(f"{path}: \"clicks\" is not a list. Answer the file ssnerf-label --suggest-clicks "
                                "wrote, changing only each \"class\".")
    annotations = Annotations(path, "clicks", labels=list(classes), skipped=Counter())
    for number, click in enumerate(clicks):
        where = f"{path}: click {number}"
        if not isinstance(click, dict) or not isinstance(click.get("file_path"), str) or not _integer(
                click.get("x")) or not _integer(click.get("y")) or "class" not in click:
            raise DatasetInputError(f"{where} needs \"file_path\" (text), \"x\" and \"y\" (whole numbers) and "
                                    "\"class\" (a class name or null). Restore it as ssnerf-label wrote it.")
        name = click["class"]
        if name is None:
            annotations.skipped[UNANSWERED] += 1
            continue
        if not isinstance(name, str) or name not in classes:
            known = ", ".join(classes) if classes else "none declared"
            raise DatasetInputError(f"{where}: class {name!r} is not one of the dataset's classes ({known}). Answer "
                                    "with one of them (or null to skip), or declare it first: ssnerf-label DATA "
                                    "--semantic-classes ...")
        file_path = index.find(click["file_path"], path)
        width, height = index.size(file_path)
        x, y = click["x"], click["y"]
        if not (0 <= x < width and 0 <= y < height):
            raise DatasetInputError(f"{where}: pixel ({x}, {y}) is outside frame {file_path}'s {width}x{height} image. "
                                    "Keep each click's x and y as suggested, or remove the click.")
        mask = np.zeros((height, width), dtype=bool)
        mask[y, x] = True
        annotations.frames.setdefault(file_path, FrameShapes(path)).shapes.append(Shape(name, mask_rle(mask)))
    return annotations
