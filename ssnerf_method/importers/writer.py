"""What both importers share: turning source pixels into our encodings (docs/dataset-format.md), and writing frames
and transforms.json with a `DatasetWriter` (into a `StagedOutputFolder`, so a failed import leaves nothing)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ssnerf_method.data.io import DatasetInputError, encode_png, write_json_atomic
from ssnerf_method.properties import REGISTRY

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
"""File name endings (any case) read as images."""

LABEL_FILE_KEYS: dict[str, str] = {
    "depth": "depth_file_path",
    **{spec.name: spec.file_key for spec in REGISTRY.values() if spec.file_key is not None},
}
"""Per-frame transforms.json key of each label folder we write (the folder is named after the property)."""

SPLITS = ("train", "val", "test")


def require_folder(path: Path, what: str) -> Path:
    if not path.is_dir():
        raise DatasetInputError(f"{path}: not a folder. It should be {what}.")
    return path


def check_destination(source: Path, destination: Path) -> None:
    """Refuse an output folder that is, or contains, the source (overwriting it would delete the source)."""
    source, destination = source.resolve(), destination.resolve()
    if destination == source or destination in source.parents:
        raise DatasetInputError(f"{destination}: output folder holds the source {source}. Pick another output folder.")


def list_images(folder: Path) -> list[Path]:
    return sorted(path for path in folder.iterdir() if path.is_file() and path.suffix.lower() in IMAGE_SUFFIXES)


def to_uint8(image: np.ndarray, path: Path) -> np.ndarray:
    """An 8-bit copy of an 8- or 16-bit image (16-bit values are rescaled so that 65535 -> 255)."""
    if image.dtype == np.uint8:
        return image
    if image.dtype == np.uint16:
        return np.round(image.astype(np.float64) / 257.0).astype(np.uint8)
    raise DatasetInputError(f"{path}: pixel type {image.dtype} is not 8- or 16-bit. Re-export it as an 8-bit PNG.")


def as_rgb(image: np.ndarray, path: Path) -> np.ndarray:
    """(H, W, 3) uint8 RGB from a grey, RGB or RGBA image (alpha dropped)."""
    if image.ndim == 2:
        image = np.repeat(image[..., None], 3, axis=-1)
    if image.ndim != 3 or image.shape[2] < 3:
        raise DatasetInputError(f"{path}: expected a colour image, got shape {image.shape}. Re-export it as RGB.")
    return to_uint8(np.ascontiguousarray(image[..., :3]), path)


def first_channel(image: np.ndarray) -> np.ndarray:
    """(H, W) first channel of an image (a single-channel image as is), keeping its pixel type."""
    return image if image.ndim == 2 else np.ascontiguousarray(image[..., 0])


def resize(image: np.ndarray, width: int, height: int, nearest: bool) -> np.ndarray:
    """`image` at (width, height): nearest neighbour for ids and depth, pixel-area averaging otherwise."""
    if image.shape[:2] == (height, width):
        return image
    return cv2.resize(image, (width, height), interpolation=cv2.INTER_NEAREST if nearest else cv2.INTER_AREA)


def centred_pinhole(focal: float, width: int, height: int) -> dict[str, Any]:
    """transforms.json intrinsics of a distortion-free camera with square pixels and a centred principal point."""
    return {
        "camera_model": "OPENCV",
        "fl_x": float(focal), "fl_y": float(focal), "cx": width / 2.0, "cy": height / 2.0, "w": width, "h": height,
        "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0,
    }  # fmt: skip


@dataclass
class ImportSummary:
    """What an import wrote, for the console report."""

    transforms_path: Path
    layout: str
    width: int
    height: int
    split_sizes: dict[str, int]
    """Frames per split (val and test are the same frames)."""
    label_counts: dict[str, int]
    """Frames holding each label, by property name (and "depth")."""
    num_frames: int
    classes: list[str] = field(default_factory=list)
    """Lines describing the class list and how source ids were mapped."""
    notes: list[str] = field(default_factory=list)
    """Anything else the user should know (resized files, unmapped names, the next step)."""

    def report(self) -> str:
        splits = ", ".join(f"{name} {self.split_sizes.get(name, 0)}" for name in SPLITS)
        labels = ", ".join(
            name if count == self.num_frames else f"{name} ({count}/{self.num_frames} frames)"
            for name, count in self.label_counts.items()
        )
        lines = [
            f"wrote {self.transforms_path} from a {self.layout} source",
            f"  frames: {self.num_frames} at {self.width}x{self.height} ({splits})",
            f"  properties: rgb{', ' + labels if labels else ''}",
            *(f"  classes: {line}" if i == 0 else f"           {line}" for i, line in enumerate(self.classes)),
            *(f"  note: {note}" for note in self.notes),
        ]
        return "\n".join(lines)


class DatasetWriter:
    """Frames of the SS-NeRF dataset format, written as they come into `root`, then its transforms.json."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self.frames: list[dict[str, Any]] = []
        self.label_counts: dict[str, int] = {}

    def _write_png(self, relative: str, image: np.ndarray) -> None:
        path = self.root / relative
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(encode_png(image))

    def add_frame(self, index: int, rgb: np.ndarray, camera_to_world: np.ndarray, labels: dict[str, np.ndarray]) -> str:
        """Write frame `index` (`frame_XXXXX.png`) and return its `file_path`: (H, W, 3) uint8 `rgb`, a 4x4 OpenGL
        pose, and `labels` by property (or "depth") already encoded (uint16 depth, uint8 maps, (H, W, 3) normals)."""
        name = f"frame_{index:05d}.png"
        frame: dict[str, Any] = {"file_path": f"images/{name}", "transform_matrix": camera_to_world.tolist()}
        self._write_png(frame["file_path"], rgb)
        for prop, image in labels.items():
            frame[LABEL_FILE_KEYS[prop]] = f"{prop}/{name}"
            self._write_png(frame[LABEL_FILE_KEYS[prop]], image)
            self.label_counts[prop] = self.label_counts.get(prop, 0) + 1
        self.frames.append(frame)
        return frame["file_path"]

    def write_transforms(
        self,
        intrinsics: dict[str, Any],
        splits: dict[str, Sequence[str]],
        provenance: dict[str, Any],
        semantic_classes: Sequence[str] | None = None,
        semantic_colors: Sequence[tuple[int, int, int]] | None = None,
        provenance_key: str = "ssnerf_import",
    ) -> Path:
        """Write transforms.json: `intrinsics`, classes, splits, frames, and `provenance` under `provenance_key`."""
        transforms: dict[str, Any] = dict(intrinsics)
        if semantic_classes is not None:
            transforms["semantic_classes"] = list(semantic_classes)
            if semantic_colors is not None:
                transforms["semantic_colors"] = [list(color) for color in semantic_colors]
        transforms.update({f"{name}_filenames": list(splits[name]) for name in SPLITS})
        transforms[provenance_key] = provenance
        transforms["frames"] = self.frames
        path = self.root / "transforms.json"
        write_json_atomic(path, transforms)
        return path

    def summary(
        self, destination: Path, layout: str, width: int, height: int, splits: dict[str, list[str]]
    ) -> ImportSummary:
        """The console report's starting point for what this writer wrote (into `destination` once moved there)."""
        return ImportSummary(
            transforms_path=destination / "transforms.json",
            layout=layout,
            width=width,
            height=height,
            split_sizes={name: len(files) for name, files in splits.items()},
            label_counts=self.ordered_label_counts(),
            num_frames=len(self.frames),
        )

    def ordered_label_counts(self) -> dict[str, int]:
        """`label_counts` in the property registry's order, depth last."""
        order = [*REGISTRY, "depth"]
        return {name: self.label_counts[name] for name in order if name in self.label_counts}
