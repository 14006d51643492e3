"""`ssnerf-import semantic-nerf`: one sequence of Semantic-NeRF's Replica renders.

Source layout: `rgb/rgb_N.png`, `depth/depth_N.png` (uint16 mm), `semantic_class/semantic_class_N.png` (Replica ids)
and `traj_w_c.txt` (line N: frame N's camera-to-world 4x4, row-major, OpenCV axes x right, y down, z forward); 90
degree HFoV pinhole. Frames 0, 5, 10, ... train, 2, 7, 12, ... test (as Semantic-NeRF); `ssnerf-label` adds the rest.
"""

from __future__ import annotations

import json
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import numpy as np
import tyro

from ssnerf_method.data.classes import SEMANTIC_CLASSES, SEMANTIC_COLORS
from ssnerf_method.data.io import DatasetInputError, StagedOutputFolder, read_image
from ssnerf_method.importers.replica_classes import VOID, replica_to_nyu13
from ssnerf_method.importers.writer import (
    DatasetWriter,
    ImportSummary,
    as_rgb,
    centred_pinhole,
    check_destination,
    first_channel,
    require_folder,
    resize,
)
from ssnerf_method.properties import SEMANTIC_IGNORE

LAYOUT = "semantic-nerf"

FRAME_STEP = 5
"""Frames i with i % FRAME_STEP == TRAIN_OFFSET train, those with i % FRAME_STEP == TEST_OFFSET test (and val)."""
TRAIN_OFFSET = 0
TEST_OFFSET = 2

HFOV_DEG = 90.0
"""Horizontal field of view of Semantic-NeRF's Replica renders."""

OPENCV_TO_OPENGL = np.diag([1.0, -1.0, -1.0, 1.0])
"""Right-multiplied onto an OpenCV camera-to-world: negates the y (down) and z (forward) axis columns."""

INFO_FILE = "info_semantic.json"
"""Replica's class list (habitat), looked for in the sequence folder when --replica-info is not given."""

FRAME_NAME = re.compile(r"^rgb_(\d+)\.png$")


@dataclass
class SemanticNeRFImportConfig:
    """Import one sequence of Semantic-NeRF's Replica renders into the SS-NeRF format (RGB, depth, semantics)."""

    src: Annotated[Path, tyro.conf.Positional, tyro.conf.arg(metavar="SRC")]
    """Sequence folder: rgb/, traj_w_c.txt and optionally depth/, semantic_class/, info_semantic.json."""
    dst: Annotated[Path, tyro.conf.Positional, tyro.conf.arg(metavar="DST")]
    """Output folder (must be missing or empty unless --overwrite)."""
    downscale: int = 1
    """Integer image downscale (2: the paper's 320x240 from 640x480); depth and semantics by nearest neighbour."""
    replica_info: Path | None = None
    """Replica's info_semantic.json, whose names map to NYUv2-13 (default: SRC's if present; else ids are remapped
    to contiguous classes, 0 = void)."""
    overwrite: bool = False
    """Replace a non-empty output folder (only once the import has succeeded)."""

    def run(self) -> ImportSummary:
        return import_semantic_nerf(self)


@dataclass
class ClassMapping:
    """How the source's class ids become ours."""

    lookup: np.ndarray
    """(max source id + 1,) uint8: our class id of each source id."""
    names: list[str]
    colors: Sequence[tuple[int, int, int]] | None
    summary: list[str]
    notes: list[str]


def _frame_numbers(src: Path) -> list[int]:
    """Frame numbers N of rgb/rgb_N.png, in numeric order (rgb_10 after rgb_9)."""
    folder = require_folder(src / "rgb", "the sequence's RGB frames rgb_0.png, rgb_1.png, ...")
    numbers = sorted(int(match.group(1)) for path in folder.iterdir() if (match := FRAME_NAME.match(path.name)))
    if not numbers:
        raise DatasetInputError(f"{folder}: no rgb_N.png files. Point SRC at a Semantic-NeRF sequence folder.")
    return numbers


def _load_trajectory(src: Path, numbers: list[int]) -> np.ndarray:
    """(N, 4, 4) OpenCV camera-to-world matrices, one per line of traj_w_c.txt."""
    path = src / "traj_w_c.txt"
    if not path.is_file():
        raise DatasetInputError(f"{path}: missing. A Semantic-NeRF sequence needs its camera file traj_w_c.txt.")
    try:
        rows = np.loadtxt(path, ndmin=2, dtype=np.float64)
    except ValueError as err:
        raise DatasetInputError(f"{path}: cannot be read as rows of 16 numbers ({err}). Check the file.") from err
    if rows.shape[1] != 16:
        raise DatasetInputError(f"{path}: lines hold {rows.shape[1]} numbers, expected 16 (a 4x4 matrix per line).")
    if len(rows) != len(numbers):
        raise DatasetInputError(
            f"{path}: {len(rows)} camera poses but {len(numbers)} images in {src / 'rgb'}; line N is the pose of "
            "rgb_N.png. Remove extra images or regenerate the trajectory."
        )
    if numbers != list(range(len(numbers))):
        raise DatasetInputError(f"{src / 'rgb'}: frame numbers must run 0..{len(numbers) - 1} without gaps.")
    return rows.reshape(-1, 4, 4)


def load_replica_classes(path: Path) -> dict[int, str]:
    """Replica class id -> name from a habitat info_semantic.json ({"classes": [{"id": int, "name": str}, ...]})."""
    if not path.is_file():
        raise DatasetInputError(f"{path}: Replica class file not found. Check --replica-info.")
    try:
        classes = json.loads(path.read_text())["classes"]
        return {int(entry["id"]): str(entry["name"]) for entry in classes}
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise DatasetInputError(
            f'{path}: not a Replica info_semantic.json with a "classes" list of {{"id", "name"}} ({err!r}).'
        ) from err


def nyu13_mapping(present: Sequence[int], replica_names: dict[int, str]) -> ClassMapping:
    """Map each present Replica class, by name, to NYUv2-13 (`replica_classes`); unknown ids become void."""
    lookup = np.zeros(max(present) + 1, dtype=np.uint8)
    grouped: dict[str, list[str]] = {}
    unlisted: list[str] = []
    unknown_ids: list[int] = []
    for raw in present:
        if raw not in replica_names:
            target = VOID
            if raw != 0:
                unknown_ids.append(raw)
        else:
            target, listed = replica_to_nyu13(replica_names[raw])
            if not listed:
                unlisted.append(replica_names[raw])
            grouped.setdefault(target, []).append(replica_names[raw])
        lookup[raw] = SEMANTIC_CLASSES.index(target)
    summary = [f"{len(present)} Replica classes present, mapped by name to NYUv2-13 + void:"]
    summary += [f"{target} <- {', '.join(names)}" for target, names in sorted(grouped.items())]
    notes = []
    if unlisted:
        notes.append(f"Replica classes not in the name table, imported as objects: {', '.join(unlisted)}")
    if unknown_ids:
        notes.append(f"class ids {unknown_ids} are not in the Replica class list: imported as void")
    return ClassMapping(lookup, list(SEMANTIC_CLASSES), SEMANTIC_COLORS, summary, notes)


def contiguous_mapping(present: Sequence[int]) -> ClassMapping:
    """Semantic-NeRF's remap without a class list: 0 stays void, the other present ids become 1, 2, ... in order."""
    others = [raw for raw in present if raw != 0]
    if len(others) >= SEMANTIC_IGNORE:
        raise DatasetInputError(f"{len(others) + 1} classes present; at most {SEMANTIC_IGNORE} fit in 8-bit labels.")
    lookup = np.zeros(max(present) + 1, dtype=np.uint8)
    lookup[others] = np.arange(1, len(others) + 1)
    summary = [
        f"no Replica class list: {len(others)} ids remapped to contiguous classes (0 = void): "
        + ", ".join(f"{raw}->{new}" for new, raw in enumerate(others, start=1))
    ]
    return ClassMapping(lookup, [VOID, *(f"class_{raw}" for raw in others)], None, summary, [])


def _read_semantics(src: Path, numbers: Sequence[int]) -> dict[int, np.ndarray]:
    """Frame number -> (H, W) uint8/uint16 source class ids, for the frames that have a semantic_class file."""
    folder = src / "semantic_class"
    semantics = {}
    for number in numbers:
        path = folder / f"semantic_class_{number}.png"
        if path.is_file():
            ids = first_channel(read_image(path, "semantic class map"))
            if ids.dtype not in (np.uint8, np.uint16):
                raise DatasetInputError(f"{path}: class ids must be an 8- or 16-bit PNG, got {ids.dtype}.")
            semantics[number] = ids
    return semantics


def _read_depth(path: Path) -> np.ndarray:
    """(H, W) uint16 millimetre depth; every imported frame needs one once the sequence has depth/."""
    if not path.is_file():
        raise DatasetInputError(
            f"{path}: missing while other frames have depth (nerfstudio needs depth for all frames or none). "
            "Add the file, or move depth/ away to import without depth."
        )
    depth = read_image(path, "depth map")
    if depth.ndim != 2 or depth.dtype != np.uint16:
        raise DatasetInputError(
            f"{path}: depth must be a single-channel 16-bit PNG in millimetres, got {depth.shape} {depth.dtype}."
        )
    return depth


def import_semantic_nerf(config: SemanticNeRFImportConfig) -> ImportSummary:
    """Convert the sequence at `config.src` into the SS-NeRF dataset format at `config.dst`."""
    src = require_folder(config.src, "a Semantic-NeRF sequence folder (rgb/, depth/, semantic_class/, traj_w_c.txt)")
    check_destination(src, config.dst)
    if config.downscale < 1:
        raise DatasetInputError(f"--downscale {config.downscale}: must be a whole number of at least 1.")
    numbers = _frame_numbers(src)
    poses = _load_trajectory(src, numbers) @ OPENCV_TO_OPENGL
    info_path = config.replica_info or (src / INFO_FILE if (src / INFO_FILE).is_file() else None)
    replica_names = load_replica_classes(info_path) if info_path is not None else None
    selected = [n for n in numbers if n % FRAME_STEP in (TRAIN_OFFSET, TEST_OFFSET)]

    has_depth = (src / "depth").is_dir()
    splits: dict[str, list[str]] = {"train": [], "val": [], "test": []}
    source_size: tuple[int, int] = (0, 0)
    width = height = 0
    with StagedOutputFolder(config.dst, config.overwrite) as staging:
        semantics = _read_semantics(src, selected)
        mapping = None
        if semantics:
            present = sorted(set().union(*(np.unique(ids).tolist() for ids in semantics.values())))
            mapping = contiguous_mapping(present) if replica_names is None else nyu13_mapping(present, replica_names)
        writer = DatasetWriter(staging)
        for number in selected:
            path = src / "rgb" / f"rgb_{number}.png"
            rgb = as_rgb(read_image(path), path)
            if number == selected[0]:
                source_size = rgb.shape[:2]
                height, width = source_size[0] // config.downscale, source_size[1] // config.downscale
                if min(height, width) < 1:
                    raise DatasetInputError(f"--downscale {config.downscale}: larger than the {path} image.")
            elif rgb.shape[:2] != source_size:
                raise DatasetInputError(
                    f"{path}: image is {rgb.shape[1]}x{rgb.shape[0]} but rgb_{selected[0]}.png is "
                    f"{source_size[1]}x{source_size[0]}. All frames of a sequence must have one size."
                )
            labels = {}
            if has_depth:
                labels["depth"] = resize(_read_depth(src / "depth" / f"depth_{number}.png"), width, height, True)
            if mapping is not None and number in semantics:
                labels["semantics"] = resize(mapping.lookup[semantics.pop(number)], width, height, True)
            file_path = writer.add_frame(number, resize(rgb, width, height, nearest=False), poses[number], labels)
            for split in ("train",) if number % FRAME_STEP == TRAIN_OFFSET else ("val", "test"):
                splits[split].append(file_path)

        provenance = {
            "tool": "ssnerf-import",
            "layout": LAYOUT,
            "source": str(src.resolve()),
            "replica_info": str(info_path.resolve()) if info_path is not None else None,
            "downscale": config.downscale,
            "source_size": [int(source_size[1]), int(source_size[0])],
            "conventions": {
                "poses": "traj_w_c.txt OpenCV camera-to-world (x right, y down, z forward), y and z columns negated",
                "intrinsics": f"pinhole, horizontal FoV {HFOV_DEG:g} deg, principal point at the image centre",
                "depth": "uint16 millimetres, copied (nearest-neighbour downscale)",
                "semantics": "Replica names -> NYUv2-13" if replica_names is not None else "contiguous remap, 0 = void",
                "split": f"train: frame % {FRAME_STEP} == {TRAIN_OFFSET}; test and val: frame % {FRAME_STEP} == "
                f"{TEST_OFFSET}",
            },
        }
        writer.write_transforms(
            centred_pinhole(width / 2.0 / np.tan(np.deg2rad(HFOV_DEG / 2.0)), width, height),
            splits,
            provenance,
            semantic_classes=mapping.names if mapping is not None else None,
            semantic_colors=mapping.colors if mapping is not None else None,
        )

    summary = writer.summary(config.dst, LAYOUT, width, height, splits)
    if mapping is not None:
        summary.classes.extend(mapping.summary)
        summary.notes.extend(mapping.notes)
    summary.notes.append(f"run `ssnerf-label {config.dst}` to add normals, shading, keypoints and edges")
    return summary
