"""Semantic annotations made with labelling tools, as `ssnerf-label --annotations PATH` reads them: shapes per frame
(each a class name and its pixels as a COCO run-length encoding), turned into a class-id image per annotated frame.

Every format (`coco.py`, `labelme.py`; `sources.load_annotations` tells them apart) is read and checked in full before
any frame is labelled: images are matched to the dataset's frames, classes to its class list, and every shape is
converted to an RLE at its frame's image size (polygons by `pycocotools`), so a bad file stops the run before anything
is written. A folder of mask PNGs is read per frame as `--semantics-dir` reads it (`sources.py`).

Coordinates are continuous image coordinates with pixel (col, row) covering [col, col + 1) x [row, row + 1), as in
COCO and in labelme's canvas: a polygon along pixel edges covers exactly the pixels inside it. Where shapes overlap,
the smaller one (fewer pixels) wins, so objects drawn over walls and tables keep their class; pixels no shape covers
are unlabelled (255).
"""

from __future__ import annotations

import json
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import Any, Dict, List, Literal, Optional, Sequence, Tuple

import numpy as np
from pycocotools import mask as coco_mask

from ssnerf_method.data.io import DatasetInputError, image_size
from ssnerf_method.data.transforms import Transforms
from ssnerf_method.label_makers.encoding import SEMANTIC_IGNORE

Format = Literal["coco", "labelme", "masks", "clicks"]

VERTEX_MARGIN = 1.0
"""How far (pixels) a polygon vertex may lie beyond the image before the polygon is refused: tools snap vertices to
the border or a little past it; more than this means the annotation belongs to another image size."""


@dataclass(frozen=True)
class Shape:
    """One annotated region: its class name and its pixels as a compressed COCO RLE at its frame's image size."""

    label: str
    rle: Dict[str, Any]

    @property
    def area(self) -> int:
        return int(coco_mask.area(self.rle))


@dataclass
class FrameShapes:
    """The shapes of one frame and the file they came from."""

    source: Path
    shapes: List[Shape] = field(default_factory=list)


@dataclass
class Annotations:
    """What an annotation source labels: per frame (its transforms `file_path`) the shapes, and the class names in the
    order the source declares them."""

    source: Path
    format: Format
    frames: Dict[str, FrameShapes] = field(default_factory=dict)
    labels: List[str] = field(default_factory=list)
    """Class names in the order the source declares them (COCO's categories as listed; labelme's labels as met)."""
    skipped: Counter = field(default_factory=Counter)
    """Shapes that label no pixels, by kind (labelme's lines and points, COCO annotations without a segmentation)."""

    def used_labels(self) -> List[str]:
        """Class names some shape uses, in declaration order."""
        used = {shape.label for frame in self.frames.values() for shape in frame.shapes}
        return [label for label in self.labels if label in used]

    def class_ids(self, file_path: str, classes: Sequence[str], height: int, width: int) -> np.ndarray:
        """(H, W) uint8 class ids of a frame: each shape painted in its class, largest first so that smaller shapes
        win where they overlap (shapes of equal size: the later one); 255 where no shape is."""
        ids = np.full((height, width), SEMANTIC_IGNORE, dtype=np.uint8)
        index = {name: class_id for class_id, name in enumerate(classes)}
        shapes = self.frames[file_path].shapes
        order = sorted(range(len(shapes)), key=lambda i: -shapes[i].area)  # stable: equal areas keep file order
        for i in order:
            ids[coco_mask.decode(shapes[i].rle).astype(bool)] = index[shapes[i].label]
        return ids


def normalised(name: str) -> PurePosixPath:
    """An image path as tools write it (Windows separators, `./`), comparable with a frame's `file_path`."""
    return PurePosixPath(*[part for part in PurePosixPath(name.replace("\\", "/")).parts if part not in (".", "")])


class FrameIndex:
    """Finds the frame an annotated image belongs to: by its path (relative to the dataset, or to the annotation file
    where the format says so), else by its file name when exactly one frame has it."""

    def __init__(self, transforms: Transforms) -> None:
        self.transforms = transforms
        self._by_path = {normalised(frame["file_path"]): frame["file_path"] for frame in transforms.frames}
        self._by_file = {(transforms.folder / frame["file_path"]).resolve(): frame["file_path"]
                         for frame in transforms.frames}
        self._by_name: Dict[str, List[str]] = {}
        for frame in transforms.frames:
            self._by_name.setdefault(normalised(frame["file_path"]).name, []).append(frame["file_path"])
        self._sizes: Dict[str, Tuple[int, int]] = {}
        self._claimed: Dict[str, str] = {}

    def find(self, name: str, where: Path, relative_to: Optional[Path] = None, entry: str = "") -> str:
        """The `file_path` of the frame whose image is `name`, annotated by `entry` (e.g. a COCO image id) of file
        `where`; `relative_to`: the folder `name` is relative to, when the format says so (labelme). Two entries
        matching one frame are refused."""
        path = normalised(name)
        by_file = (relative_to / path).resolve() if relative_to is not None else None
        if by_file is not None and by_file in self._by_file:
            file_path = self._by_file[by_file]
        elif path in self._by_path:
            file_path = self._by_path[path]
        else:
            named = self._by_name.get(path.name, [])
            if len(named) > 1:
                raise DatasetInputError(
                    f"{where}: image {name!r} matches frames {named[0]} and {named[1]} of {self.transforms.path} by "
                    "file name. Give its path relative to the dataset folder (as the frame's file_path)."
                )
            if not named:
                raise DatasetInputError(
                    f"{where}: image {name!r} matches no frame of {self.transforms.path} (by path or file name). "
                    "Rename it as its frame's file_path, or remove it from the annotations."
                )
            file_path = named[0]
        claim = f"{where}{entry}"
        earlier = self._claimed.setdefault(file_path, claim)
        if earlier != claim:
            raise DatasetInputError(
                f"{where}: image {name!r}{entry} is frame {file_path}, which {earlier} annotates too. Keep one "
                "annotation entry per frame (merge them)."
            )
        return file_path

    def size(self, file_path: str) -> Tuple[int, int]:
        """(width, height) of a frame's image, read from its header."""
        if file_path not in self._sizes:
            self._sizes[file_path] = image_size(self.transforms.file(file_path), "image")
        return self._sizes[file_path]


def read_json(path: Path, what: str) -> Any:
    """A JSON file, or one line naming it."""
    try:
        return json.loads(path.read_text())
    except (OSError, UnicodeDecodeError) as err:
        raise DatasetInputError(f"{path}: cannot be read ({err}). Check the --annotations path.") from err
    except json.JSONDecodeError as err:
        raise DatasetInputError(
            f"{path}: not valid JSON ({err.msg} at line {err.lineno}, column {err.colno}). Re-export the {what}."
        ) from err


def check_vertices(xs: np.ndarray, ys: np.ndarray, width: int, height: int, where: str) -> None:
    """Refuse vertices more than `VERTEX_MARGIN` beyond the image (the annotation is of another image size)."""
    if (xs.min() < -VERTEX_MARGIN or ys.min() < -VERTEX_MARGIN or xs.max() > width + VERTEX_MARGIN
            or ys.max() > height + VERTEX_MARGIN):
        raise DatasetInputError(
            f"{where}: vertices reach x {xs.min():g}..{xs.max():g}, y {ys.min():g}..{ys.max():g}, outside the "
            f"{width}x{height} image. The shape was drawn on another image size: re-export it for this one."
        )


def polygon_rle(polygons: Sequence[Sequence[float]], width: int, height: int, where: str) -> Dict[str, Any]:
    """The RLE of the union of flat [x0, y0, x1, y1, ...] polygons, rasterised by pycocotools; a polygon with fewer
    than 3 vertices, non-numbers, or a vertex more than `VERTEX_MARGIN` beyond the image is refused."""
    checked = []
    for polygon in polygons:
        try:
            values = np.asarray(polygon, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            raise DatasetInputError(f"{where}: a polygon is not a list of numbers. Fix or remove the shape.") from None
        if values.size < 6 or values.size % 2 or not np.isfinite(values).all():
            raise DatasetInputError(
                f"{where}: a polygon needs at least 3 (x, y) vertices of finite numbers, got {values.size} values. "
                "Fix or remove the shape."
            )
        check_vertices(values[0::2], values[1::2], width, height, where)
        checked.append(values.tolist())
    return coco_mask.merge(coco_mask.frPyObjects(checked, height, width))


def mask_rle(mask: np.ndarray) -> Dict[str, Any]:
    """The RLE of a boolean (H, W) mask."""
    return coco_mask.encode(np.asfortranarray(mask.astype(np.uint8)))
