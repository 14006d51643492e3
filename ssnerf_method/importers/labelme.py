"""labelme JSON files (one per image: `shapes`, `imagePath`, `imageHeight`, `imageWidth`) as `Annotations`.

`imagePath` is relative to the JSON file (labelme's rule); it is matched to a frame by that path, else by file name.
Polygons and rectangles (two opposite corners, drawn as their 4-corner polygon) are rasterised by pycocotools; a
circle (its centre and a point on it) covers the pixels whose centre (col + 0.5, row + 0.5) lies within its radius.
Lines, line strips and points label no pixels: they are counted as skipped.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Dict, List, Optional

import numpy as np

from ssnerf_method.data.io import DatasetInputError
from ssnerf_method.importers.annotations import (
    Annotations,
    FrameIndex,
    FrameShapes,
    Shape,
    check_vertices,
    mask_rle,
    polygon_rle,
    read_json,
)

AREA_SHAPES = ("polygon", "rectangle", "circle")
"""labelme shape types that cover pixels; every other type (line, linestrip, point, points, ...) is skipped."""


def read_labelme_files(
    folder: Path, files: List[Path], index: FrameIndex, parsed: Optional[Dict[Path, Any]] = None,
    source: Optional[Path] = None,
) -> Annotations:
    """The annotations of labelme `files` (already parsed ones in `parsed`); `source` is what the user named (the
    folder, or the one file)."""
    annotations = Annotations(source or folder, "labelme")
    for path in files:
        content = (parsed or {}).get(path)
        if content is None:
            content = read_json(path, "labelme annotations")
        if not isinstance(content, dict) or not isinstance(content.get("shapes"), list) \
                or not isinstance(content.get("imagePath"), str):
            raise DatasetInputError(
                f"{path}: not a labelme file (needs \"shapes\" and \"imagePath\"). Keep only labelme .json files "
                "in the --annotations folder."
            )
        file_path = index.find(content["imagePath"], path, relative_to=path.parent)
        width, height = index.size(file_path)
        given = (content.get("imageWidth", width), content.get("imageHeight", height))
        if given != (width, height):
            raise DatasetInputError(
                f"{path}: annotates a {given[0]}x{given[1]} image but frame {file_path} is {width}x{height}. Annotate "
                "the dataset's images."
            )
        frame = annotations.frames.setdefault(file_path, FrameShapes(path))
        for number, shape in enumerate(content["shapes"]):
            parsed_shape = _shape(shape, width, height, f"{path}: shape {number} (frame {file_path})")
            if isinstance(parsed_shape, str):
                annotations.skipped[parsed_shape] += 1
                continue
            frame.shapes.append(parsed_shape)
            if parsed_shape.label not in annotations.labels:
                annotations.labels.append(parsed_shape.label)
    return annotations


def _shape(shape: Any, width: int, height: int, where: str) -> Shape | str:
    """A labelme shape as a `Shape`, or the name of its type when it covers no pixels."""
    if not isinstance(shape, dict) or not isinstance(shape.get("label"), str) or not shape["label"]:
        raise DatasetInputError(f"{where}: has no \"label\". Name its class in labelme.")
    kind = shape.get("shape_type") or "polygon"  # labelme's default
    if kind not in AREA_SHAPES:
        return str(kind)
    try:
        points = np.asarray(shape.get("points"), dtype=np.float64)
    except (TypeError, ValueError):
        raise DatasetInputError(f"{where}: \"points\" is not a list of [x, y] pairs. Fix or redraw it.") from None
    needed = 3 if kind == "polygon" else 2
    if points.ndim != 2 or points.shape[1] != 2 or len(points) < needed or (kind != "polygon" and len(points) != 2):
        raise DatasetInputError(
            f"{where}: a {kind} needs {'at least 3' if kind == 'polygon' else 'exactly 2'} [x, y] points. Fix or "
            "redraw it."
        )
    if kind == "polygon":
        return Shape(shape["label"], polygon_rle([points.reshape(-1)], width, height, where))
    (x0, y0), (x1, y1) = points
    if kind == "rectangle":
        left, right, top, bottom = min(x0, x1), max(x0, x1), min(y0, y1), max(y0, y1)
        corners = [left, top, right, top, right, bottom, left, bottom]
        return Shape(shape["label"], polygon_rle([corners], width, height, where))
    check_vertices(np.array([x0]), np.array([y0]), width, height, where)  # its centre
    cols, rows = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    inside = (cols - x0) ** 2 + (rows - y0) ** 2 <= (x1 - x0) ** 2 + (y1 - y0) ** 2
    return Shape(shape["label"], mask_rle(inside))
