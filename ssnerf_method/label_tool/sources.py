"""What `ssnerf-label` reads for the label makers: depth maps, class ids from a folder of masks (as ids, or as colours
listed in transforms.json), and the annotation files of `--annotations` (COCO, labelme, or such a folder)."""

from __future__ import annotations

from pathlib import Path, PurePosixPath
from typing import Dict, Optional

import numpy as np

from ssnerf_method.data.io import DatasetInputError, read_image
from ssnerf_method.data.transforms import Transforms
from ssnerf_method.importers import clicks, coco, labelme
from ssnerf_method.importers.annotations import Annotations, FrameIndex, read_json
from ssnerf_method.label_makers.encoding import SEMANTIC_IGNORE
from ssnerf_method.label_makers.makers import Skip


def read_depth(path: Path) -> np.ndarray:
    """A depth map as float (.npy, or a single-channel 16/32-bit image); units do not matter for normals."""
    if path.suffix == ".npy":
        try:
            depth = np.load(path).astype(np.float64)
        except (OSError, ValueError) as err:
            raise DatasetInputError(f"{path}: depth .npy cannot be read ({err}). Re-export it.") from err
        depth = depth[..., 0] if depth.ndim == 3 and depth.shape[2] == 1 else depth
    else:
        depth = read_image(path, "depth map").astype(np.float64)
    if depth.ndim != 2:
        raise DatasetInputError(
            f"{path}: depth must be one channel (16-bit PNG in millimetres, or .npy), got shape {depth.shape}. "
            "Fix depth_file_path or re-export the depth."
        )
    if not (np.isfinite(depth) & (depth > 0)).any():
        raise DatasetInputError(
            f"{path}: depth is zero (or invalid) everywhere. Check that depth_file_path points at the depth map, or "
            "remove the key from that frame (its normals and shading are then skipped)."
        )
    return depth


def checked_depth(path: Path, width: int, height: int) -> np.ndarray:
    """`read_depth`, refusing a map whose aspect ratio is not its image's (it could not be mapped to its pixels)."""
    depth = read_depth(path)
    if abs(depth.shape[0] / height - depth.shape[1] / width) > 0.02:
        raise DatasetInputError(
            f"{path}: depth is {depth.shape[1]}x{depth.shape[0]}, not the aspect ratio of its image "
            f"({width}x{height}). Fix depth_file_path or resize the depth map."
        )
    return depth


def semantics_file(frame: Dict, folder: Path) -> Path:
    """The annotation of a frame in `folder`: its image's relative path (or name) with `.png`."""
    relative = PurePosixPath(frame["file_path"])
    stem = relative.with_suffix(".png")
    candidates = [folder / stem, folder / stem.name]
    if len(relative.parts) > 1:
        candidates.insert(1, folder / PurePosixPath(*relative.parts[1:]).with_suffix(".png"))
    for candidate in candidates:
        if candidate.is_file():
            return candidate
    raise Skip(f"no file in {folder}")


def read_class_ids(path: Path, width: int, height: int, colors: Optional[list]) -> np.ndarray:
    """(H, W) uint8 class ids of an annotation: an 8/16-bit id image, or colours looked up in `colors`."""
    labels = read_image(path, "semantic label")
    if labels.shape[:2] != (height, width):
        raise DatasetInputError(
            f"{path}: semantic label is {labels.shape[1]}x{labels.shape[0]} but its image is {width}x{height}. "
            "Resize it (nearest neighbour) to the image's size."
        )
    if labels.ndim == 3:
        if not colors:
            raise DatasetInputError(
                f"{path}: a colour-coded semantic label, but transforms.json has no \"semantic_colors\" to read it. "
                "Add the class colours (one RGB triple per class) or give class-id images."
            )
        lookup = {tuple(int(v) for v in color): index for index, color in enumerate(colors)}
        flat = labels[..., :3].reshape(-1, 3)
        unique, inverse = np.unique(flat, axis=0, return_inverse=True)
        unknown = [tuple(color) for color in unique.tolist() if tuple(color) not in lookup]
        if unknown:
            raise DatasetInputError(
                f"{path}: colours {unknown[:5]} are not in semantic_colors. Add them or relabel those pixels."
            )
        ids = np.array([lookup[tuple(color)] for color in unique.tolist()])[inverse.reshape(-1)]
        labels = ids.reshape(labels.shape[:2])
    if labels.max() > SEMANTIC_IGNORE:
        raise DatasetInputError(
            f"{path}: class id {int(labels.max())} does not fit the format (ids 0-254, 255 = unlabelled). "
            "Remap the classes to fewer ids."
        )
    return labels.astype(np.uint8)


def load_annotations(path: Path, transforms: Transforms) -> Optional[Annotations]:
    """Read and check the annotation source at `path` (a COCO or labelme .json file, a folder of labelme files, or a
    folder of mask PNGs). A folder of masks returns None: it is read per frame, as `--semantics-dir`."""
    index = FrameIndex(transforms)
    if path.is_dir():
        json_files = sorted(path.glob("*.json"))
        if json_files:
            return _with_shapes(labelme.read_labelme_files(path, json_files, index))
        if any(path.glob("*.png")) or any(path.glob("*/*.png")):
            return None
        raise DatasetInputError(
            f"{path}: holds no labelme .json files and no mask .png files. Point --annotations at a COCO .json, a "
            "labelme .json or a folder of them, or a folder of class-id PNGs named like the images."
        )
    if not path.is_file():
        raise DatasetInputError(f"{path}: does not exist. Check the --annotations path.")
    if path.suffix.lower() != ".json":
        raise DatasetInputError(
            f"{path}: not an annotation file this tool reads. Give a COCO .json (instance segmentation export), a "
            "labelme .json or a folder of them, or a folder of class-id PNGs; convert other formats to COCO first."
        )
    content = read_json(path, "annotations")
    if clicks.is_clicks_file(content):
        return _with_shapes(clicks.read_clicks(path, content, index, transforms.meta.get("semantic_classes") or []))
    if isinstance(content, dict) and "images" in content and "annotations" in content:
        return _with_shapes(coco.read_coco(path, content, index))
    if isinstance(content, dict) and "shapes" in content:
        return _with_shapes(labelme.read_labelme_files(path.parent, [path], index, {path: content}, source=path))
    raise DatasetInputError(
        f"{path}: neither a COCO file (\"images\", \"annotations\", \"categories\") nor a labelme file (\"shapes\"). "
        "Export the annotations as COCO instance segmentation or labelme JSON, or answer ssnerf-label's suggested "
        "clicks."
    )


def _with_shapes(annotations: Annotations) -> Annotations:
    """Frames whose entries hold no shape that covers pixels are not annotated (they get no semantics file)."""
    annotations.frames = {path: frame for path, frame in annotations.frames.items() if frame.shapes}
    return annotations
