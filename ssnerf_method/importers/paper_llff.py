"""`ssnerf-import paper-llff`: the SS-NeRF authors' released Replica scenes, in the LLFF layout.

Source layout: `images/000.png ...`, `poses_bounds.npy` (N x 17: row-major 3x5 [R | t | hwf], R's columns the camera's
down, right, backwards axes, hwf in pixels at the pose file's resolution; then near, far), and label folders named
like the images: `normal_new/` or `normal/` ((n + 1) / 2), `reshading/`, `keypoint/`, `edge/` (value / 255) and
`label/` (class id). Every 8th frame from 0 is test (the authors' `llffhold = 8`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import numpy as np
import tyro

from ssnerf_method.data.classes import SEMANTIC_CLASSES, SEMANTIC_COLORS
from ssnerf_method.data.io import DatasetInputError, StagedOutputFolder, read_image
from ssnerf_method.importers.writer import (
    DatasetWriter,
    ImportSummary,
    as_rgb,
    centred_pinhole,
    check_destination,
    first_channel,
    list_images,
    require_folder,
    resize,
    to_uint8,
)
from ssnerf_method.properties import REGISTRY, SEMANTIC_IGNORE

LAYOUT = "paper-llff"

SCALAR_FOLDERS: dict[str, str] = {"reshading": "shading", "keypoint": "keypoints", "edge": "edges"}
"""Source folder of each single-channel [0, 1] map -> our property name."""

NORMALS_FOLDERS: tuple[str, ...] = ("normal_new", "normal")
"""Source normals folders, preferred first (the authors' loader reads `normal_new/`, their README names `normal/`)."""

LABEL_FOLDER = "label"
"""Source folder of the class-id maps."""

DEFAULT_CLASS_NAMES: tuple[str, ...] = SEMANTIC_CLASSES[1:]
"""Class names of label ids 0..12: the NYUv2-13 classes without void, as the authors' 13-way semantic head."""

AXIS_LETTERS: dict[str, tuple[int, bool]] = {
    "R": (0, False), "L": (0, True), "U": (1, False), "D": (1, True), "B": (2, False), "F": (2, True),
}  # fmt: skip
"""Normals-axes letter -> (our OpenGL camera axis it lies along, whether it points the opposite way)."""


@dataclass
class PaperLLFFImportConfig:
    """Import one scene of the SS-NeRF authors' released Replica data (LLFF layout) into the SS-NeRF format."""

    src: Annotated[Path, tyro.conf.Positional, tyro.conf.arg(metavar="SRC")]
    """Scene folder: images/, poses_bounds.npy and the label folders (normal_new/ or normal/, reshading/, label/,
    keypoint/, edge/); missing label folders are skipped."""
    dst: Annotated[Path, tyro.conf.Positional, tyro.conf.arg(metavar="DST")]
    """Output folder (must be missing or empty unless --overwrite)."""
    class_names: tuple[str, ...] = ()
    """Names of the class ids in label/, id = position (default: the 13 NYUv2-13 classes, bed=0 ... window=12)."""
    normals_axes: str = "LUB"
    """Camera-frame direction of the source normals' +x, +y, +z, one letter each of R/L, U/D, B/F (backwards =
    towards the viewer). Ours is RUB; the paper's SN = (-dz/dx, -dz/dy, 1) in image axes gives LUB."""
    test_every: int = 8
    """Frames 0, test_every, 2*test_every, ... are the test (and val) frames, as the authors' llffhold."""
    overwrite: bool = False
    """Replace a non-empty output folder (only once the import has succeeded)."""

    def run(self) -> ImportSummary:
        return import_paper_llff(self)


def llff_poses_to_opengl(poses_bounds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, 4, 4) OpenGL camera-to-world (columns (R1, -R0, R2, t)) and (N, 3) hwf from poses_bounds.npy's rows."""
    matrices = poses_bounds[:, :15].reshape(-1, 3, 5)
    rotation, translation = matrices[:, :, :3], matrices[:, :, 3]
    camera_to_world = np.tile(np.eye(4), (len(matrices), 1, 1))
    camera_to_world[:, :3, :3] = np.stack([rotation[:, :, 1], -rotation[:, :, 0], rotation[:, :, 2]], axis=-1)
    camera_to_world[:, :3, 3] = translation
    return camera_to_world, matrices[:, :, 4]


def normals_axes_conversion(code: str) -> tuple[list[int], list[bool]]:
    """Per axis of ours, the source channel holding it and whether it is flipped, from `normals_axes` `code`."""
    letters = code.strip().upper()
    axes = [AXIS_LETTERS.get(letter) for letter in letters]
    if len(letters) != 3 or None in axes or sorted(axis for axis, _ in axes) != [0, 1, 2]:  # type: ignore[misc]
        raise DatasetInputError(
            f"--normals-axes {code!r}: give 3 letters, one each of R/L, U/D and B/F (e.g. LUB for the paper's normals, "
            "RUB for OpenGL camera axes)."
        )
    source = [0, 0, 0]
    flip = [False, False, False]
    for channel, (axis, opposite) in enumerate(axes):  # type: ignore[misc]
        source[axis], flip[axis] = channel, opposite
    return source, flip


def convert_normals(rgb: np.ndarray, source: Sequence[int], flip: Sequence[bool]) -> np.ndarray:
    """(H, W, 3) uint8 normals in the source's axes -> ours; flipping an axis maps the code v to 255 - v (n to -n)."""
    channels = [255 - rgb[..., c] if f else rgb[..., c] for c, f in zip(source, flip)]
    return np.stack(channels, axis=-1).astype(np.uint8)


def _load_poses(src: Path, num_images: int) -> np.ndarray:
    path = src / "poses_bounds.npy"
    if not path.is_file():
        raise DatasetInputError(f"{path}: missing. A paper-llff scene needs the LLFF camera file poses_bounds.npy.")
    try:
        poses_bounds = np.load(path)
    except (OSError, ValueError) as err:
        raise DatasetInputError(f"{path}: cannot be read as a NumPy array ({err}). Re-export it with np.save.") from err
    if poses_bounds.ndim != 2 or poses_bounds.shape[1] != 17:
        raise DatasetInputError(
            f"{path}: shape {poses_bounds.shape}, expected (N, 17) rows of [3x5 pose | near, far]. Check the file."
        )
    if len(poses_bounds) != num_images:
        raise DatasetInputError(
            f"{path}: {len(poses_bounds)} camera poses but {num_images} images in {src / 'images'}; each image "
            "(sorted by name) needs one row. Remove extra images or regenerate poses_bounds.npy."
        )
    return poses_bounds.astype(np.float64)


def _label_folders(src: Path) -> dict[str, Path]:
    """Our property name -> the source folder it is read from, for the folders present."""
    folders = {prop: src / name for name, prop in SCALAR_FOLDERS.items() if (src / name).is_dir()}
    normals = next((src / name for name in NORMALS_FOLDERS if (src / name).is_dir()), None)
    if normals is not None:
        folders["normals"] = normals
    if (src / LABEL_FOLDER).is_dir():
        folders["semantics"] = src / LABEL_FOLDER
    return folders


def _read_label(prop: str, path: Path, normals_map: tuple[list[int], list[bool]], num_classes: int) -> np.ndarray:
    """One source label file in our encoding (see the module docstring for the source encodings)."""
    image = read_image(path, f"{prop} label")
    if prop == "normals":
        if image.ndim != 3:
            raise DatasetInputError(f"{path}: normals must be an RGB image, got shape {image.shape}. Re-export it.")
        return convert_normals(as_rgb(image, path), *normals_map)
    if not REGISTRY[prop].kind.categorical:
        return to_uint8(first_channel(image), path)
    ids = first_channel(image)
    bad = sorted(int(i) for i in np.unique(ids) if i >= num_classes and i != SEMANTIC_IGNORE)
    if bad:
        raise DatasetInputError(
            f"{path}: class ids {bad} are outside the {num_classes} class names (ids 0-{num_classes - 1}, "
            f"{SEMANTIC_IGNORE} = unlabelled). Pass the scene's class list with --class-names NAME0 NAME1 ..."
        )
    return ids.astype(np.uint8)


def import_paper_llff(config: PaperLLFFImportConfig) -> ImportSummary:
    """Convert the scene at `config.src` into the SS-NeRF dataset format at `config.dst`."""
    src = require_folder(config.src, "a paper-llff scene folder (images/, poses_bounds.npy, label folders)")
    check_destination(src, config.dst)
    normals_map = normals_axes_conversion(config.normals_axes)
    if config.test_every < 1:
        raise DatasetInputError(f"--test-every {config.test_every}: must be at least 1.")
    class_names = tuple(config.class_names) if config.class_names else DEFAULT_CLASS_NAMES
    if len(class_names) > SEMANTIC_IGNORE:
        raise DatasetInputError(f"--class-names: {len(class_names)} names, at most {SEMANTIC_IGNORE} fit in 8 bits.")
    images = list_images(require_folder(src / "images", "the scene's RGB images (000.png, 001.png, ...)"))
    if not images:
        raise DatasetInputError(f"{src / 'images'}: no .png/.jpg images. Point SRC at a paper-llff scene folder.")
    poses_bounds = _load_poses(src, len(images))
    camera_to_world, hwf = llff_poses_to_opengl(poses_bounds)
    if not np.allclose(hwf, hwf[0], rtol=1e-4):
        raise DatasetInputError(
            f"{src / 'poses_bounds.npy'}: image size or focal length differs between frames; this importer expects "
            "one camera for the whole scene."
        )
    folders = _label_folders(src)
    sources = {prop: {path.stem: path for path in list_images(folder)} for prop, folder in folders.items()}

    splits: dict[str, list[str]] = {"train": [], "val": [], "test": []}
    width = height = 0
    resized: dict[str, int] = {}
    with StagedOutputFolder(config.dst, config.overwrite) as staging:
        writer = DatasetWriter(staging)
        for index, image_path in enumerate(images):
            rgb = as_rgb(read_image(image_path), image_path)
            if index == 0:
                height, width = rgb.shape[:2]
            elif rgb.shape[:2] != (height, width):
                raise DatasetInputError(
                    f"{image_path}: image is {rgb.shape[1]}x{rgb.shape[0]} but {images[0].name} is {width}x{height}. "
                    "All images of a scene must have one size; resize them to match."
                )
            labels = {}
            for prop, files in sources.items():
                if image_path.stem in files:
                    label = _read_label(prop, files[image_path.stem], normals_map, len(class_names))
                    if label.shape[:2] != (height, width):
                        resized[folders[prop].name] = resized.get(folders[prop].name, 0) + 1
                    labels[prop] = resize(label, width, height, nearest=REGISTRY[prop].kind.categorical)
            file_path = writer.add_frame(index, rgb, camera_to_world[index], labels)
            held_out = index % config.test_every == 0
            for split in ("val", "test") if held_out else ("train",):
                splits[split].append(file_path)

        pose_height, pose_width, focal = hwf[0]
        provenance = {
            "tool": "ssnerf-import",
            "layout": LAYOUT,
            "source": str(src.resolve()),
            "source_folders": {prop: folder.name for prop, folder in folders.items()},
            "conventions": {
                "poses": "poses_bounds.npy [R | t] with R's columns (down, right, backwards) -> (R1, -R0, R2, t)",
                "intrinsics": f"focal {focal:g} px at {pose_width:g}x{pose_height:g} scaled to the images' width",
                "normals_axes": config.normals_axes.upper(),
                "labels": "first channel; semantics = class id, shading/keypoints/edges = value / 255",
                "split": f"every {config.test_every}th frame from 0 is test and val",
            },
            "near_far": [float(poses_bounds[:, 15].min()), float(poses_bounds[:, 16].max())],
        }
        with_semantics = "semantics" in folders
        colors = SEMANTIC_COLORS[1:] if class_names == DEFAULT_CLASS_NAMES else None
        writer.write_transforms(
            centred_pinhole(focal * width / pose_width, width, height),
            splits,
            provenance,
            semantic_classes=class_names if with_semantics else None,
            semantic_colors=colors if with_semantics else None,
        )

    summary = writer.summary(config.dst, LAYOUT, width, height, splits)
    if with_semantics:
        which = "NYUv2-13 (default)" if class_names == DEFAULT_CLASS_NAMES else "from --class-names"
        ids = ", ".join(f"{i}={name}" for i, name in enumerate(class_names))
        summary.classes.append(f"{len(class_names)} {which}, source ids kept: {ids}")
    if "normals" in folders:
        summary.notes.append(f"normals read from {folders['normals'].name}/ as {config.normals_axes.upper()} axes")
    summary.notes.extend(f"resized {count} label files of {name}/ to the image size" for name, count in resized.items())
    missing = [f"{name}/" for name in (*SCALAR_FOLDERS, LABEL_FOLDER) if not (src / name).is_dir()]
    if "normals" not in folders:
        missing.append(" or ".join(f"{name}/" for name in NORMALS_FOLDERS))
    if missing:
        summary.notes.append(f"no {', '.join(missing)} in the source: not imported")
    return summary
