"""One check of a dataset against the SS-NeRF dataset format (docs/dataset-format.md) before anything is built on it.

`validate_dataset` reports every fault in one pass, one line each naming the file (or frame and key) and the fix.
Images are checked from their headers; pixels only for depth and labels (as training reads them). `ssnerf-check` and
`ssnerf-label` check everything; the dataparser only headers, since training checks pixels as it loads them.
"""

from __future__ import annotations

import json
import math
import sys
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import Callable, Collection, Dict, List, Optional, Sequence, Tuple

import cv2
import numpy as np
from PIL import Image, UnidentifiedImageError

from nerfstudio.cameras.cameras import CAMERA_MODEL_TO_TYPE

from ssnerf_method.data.io import DatasetInputError
from ssnerf_method.data.strokes import STROKES_FILE, StrokeStore
from ssnerf_method.data.transforms import DISTORTION_KEYS, INTRINSIC_KEYS
from ssnerf_method.properties import REGISTRY, LabelFileError

DEPTH_MODES = ("I;16", "I;16B", "I;16L", "I;16N", "I", "F")
"""PIL modes of a depth image nerfstudio reads as depth: 16-bit integer (millimetres) or 32-bit."""
DISTORTION_LENGTHS = {"FISHEYE624": 12}
"""Length of `distortion_params` per camera model (nerfstudio's k1, k2, k3, k4, p1, p2 for the others)."""
DEFAULT_DISTORTION_LENGTH = len(DISTORTION_KEYS)
SAVED_RUN_COMMANDS = ("ns-eval", "ns-render", "ns-viewer", "ns-export", "ssnerf-export-dataset", "ssnerf-export-points")
"""Commands that take the dataset's path from a trained run's config.yml (--load-config) rather than from --data."""
MAX_LISTED = 20
"""Faults listed in an error (`ssnerf-check` lists them all)."""


class DatasetFaults(DatasetInputError):
    """The faults `validate_dataset` found, one line each (the first `MAX_LISTED` and a count of the rest)."""

    def __init__(self, faults: Sequence[str], data: Path) -> None:
        self.faults = list(faults)
        lines = self.faults[:MAX_LISTED]
        if len(self.faults) > MAX_LISTED:
            lines.append(f"... and {len(self.faults) - MAX_LISTED} more faults: `ssnerf-check {data}` lists them all.")
        super().__init__("\n".join(lines))


@dataclass
class Validation:
    """What `validate_dataset` found."""

    transforms_path: Path
    num_frames: int = 0
    labelled: Dict[str, int] = field(default_factory=dict)
    """Per property, how many frames list a label file for it."""
    faults: List[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.faults

    def raise_if_faulty(self, data: Optional[Path] = None) -> None:
        if self.faults:
            raise DatasetFaults(self.faults, data or self.transforms_path.parent)


def transforms_file(data: Path) -> Path:
    """The transforms file nerfstudio's parser reads for `--data data` (a folder's transforms.json, or a .json)."""
    return data if data.suffix == ".json" else data / "transforms.json"


def missing_data_fix() -> str:
    """How to point the running command at a missing dataset: `--data`, or a trained run's config.yml `data:`."""
    edit = ("set `data:` under `pipeline:` -> `datamanager:` in the run's config.yml (the --load-config file) to the "
            "dataset's folder, e.g. `data: /new/place/scene`")
    program = Path(sys.argv[0]).name if sys.argv and sys.argv[0] else ""
    if program == "ns-train":
        return "Point --data at a dataset folder holding transforms.json."
    if program in SAVED_RUN_COMMANDS:
        also = " (`ns-render dataset` also takes --data)" if program == "ns-render" else ""
        return f"If the dataset has moved, {edit}{also}."
    return f"Point --data at a dataset folder holding transforms.json; for a trained model, {edit}."


def validate_dataset(
    data: Path, contents: bool = True, workers: int = 4, skip_labels: Collection[str] = ()
) -> Validation:
    """Check the dataset at `data` (folder or transforms .json); `contents=False` reads no pixels at all."""
    path = transforms_file(data)
    validation = Validation(path)
    if not data.exists():
        where = "" if data.is_absolute() else f" (relative to {Path.cwd()})"
        validation.faults.append(f"{data}: does not exist{where}. {missing_data_fix()}")
        return validation
    if not path.is_file():
        blender = (path.parent / "transforms_train.json").is_file()
        fix = ("It is a Blender-synthetic folder: run `ssnerf-label` on it to write one" if blender else
               "Point at a nerfstudio dataset folder (e.g. `ns-process-data` or `ssnerf-make-scene` output) or import "
               "the data first (`ssnerf-import`)")
        validation.faults.append(f"{path}: missing. {fix}.")
        return validation
    try:
        meta = json.loads(path.read_text())
    except UnicodeDecodeError as err:
        validation.faults.append(f"{path}: not a text file ({err.reason}). Restore it from a backup or regenerate it.")
        return validation
    except OSError as err:
        validation.faults.append(f"{path}: cannot be read ({err.strerror}). Check its permissions.")
        return validation
    except json.JSONDecodeError as err:
        validation.faults.append(
            f"{path}: not valid JSON ({err.msg} at line {err.lineno}, column {err.colno}). Restore it from a backup "
            "(ssnerf-label keeps transforms.json.orig) or regenerate it."
        )
        return validation
    validation = validate_transforms(path.parent, path, meta, contents, workers, skip_labels)
    if (path.parent / STROKES_FILE).exists():  # strokes painted in the viewer are read by every run
        try:
            StrokeStore.load(path.parent / STROKES_FILE)
        except DatasetInputError as err:
            validation.faults.append(str(err))
    return validation


def validate_transforms(
    folder: Path,
    path: Path,
    meta: object,
    contents: bool = True,
    workers: int = 4,
    skip_labels: Collection[str] = (),
) -> Validation:
    """Check parsed transforms `meta` (files relative to `folder`), except labels `ssnerf-label` will replace."""
    validation = Validation(path)
    faults = validation.faults
    if not isinstance(meta, dict) or not isinstance(meta.get("frames"), list) or not meta["frames"]:
        faults.append(f"{path}: has no \"frames\" list. It is not a nerfstudio transforms file; regenerate it.")
        return validation
    frames: List = meta["frames"]
    validation.num_frames = len(frames)
    faults.extend(_top_level_faults(path, meta))
    classes = meta.get("semantic_classes")
    num_classes = len(classes) if isinstance(classes, list) and classes else 256
    jobs: List[Callable[[], Optional[str]]] = []
    for index, frame in enumerate(frames):
        where = f"{path}, frames[{index}]"
        if not isinstance(frame, dict):
            faults.append(f"{where}: is not a JSON object. Give each frame its \"file_path\" and \"transform_matrix\".")
            continue
        if isinstance(frame.get("file_path"), str):
            where += f" ({frame['file_path']})"
        frame_faults, size = _frame_faults(where, frame, meta)
        faults.extend(frame_faults)
        jobs.extend(_file_jobs(where, folder, frame, size, num_classes, contents, skip_labels))
        for spec in REGISTRY.values():
            if spec.file_key is not None and spec.file_key in frame:
                validation.labelled[spec.name] = validation.labelled.get(spec.name, 0) + 1
    class_labels = [spec.name for spec in REGISTRY.values()
                    if spec.kind.categorical and validation.labelled.get(spec.name) and spec.name not in skip_labels]
    if class_labels and not (isinstance(classes, list) and classes and all(isinstance(name, str) for name in classes)):
        faults.append(
            f"{path}: frames list {class_labels[0]} files but there is no top-level \"semantic_classes\" list of "
            "names. Add the class names (id = index), e.g. \"semantic_classes\": [\"void\", \"bed\", ...]."
        )
    with ThreadPoolExecutor(max_workers=max(workers, 1)) as pool:
        faults.extend(fault for fault in pool.map(lambda job: job(), jobs) if fault is not None)
    return validation


def _camera_faults(where: str, camera: Dict) -> List[str]:
    """The camera model of `camera` (a frame merged over the top level, or the top level) and its parameters."""
    model = camera.get("camera_model", "OPENCV")
    if model not in CAMERA_MODEL_TO_TYPE:
        return [_unknown_model(where, model)]
    distortion = camera.get("distortion_params")
    length = DISTORTION_LENGTHS.get(model, DEFAULT_DISTORTION_LENGTH)
    if model in DISTORTION_LENGTHS and distortion is None:
        return [f"{where}: camera_model {model} needs \"distortion_params\": {length} numbers (k0-k5, p0, p1, "
                "s0-s3). Add them (per frame or at the top level)."]
    if distortion is not None and (
        not isinstance(distortion, list) or len(distortion) != length
        or any(_number(value) is None for value in distortion)
    ):
        return [f"{where}: \"distortion_params\" must be {length} finite numbers for camera_model {model}. "
                "Fix them."]
    return []


def _top_level_faults(path: Path, meta: Dict) -> List[str]:
    faults = []
    frames = [frame for frame in meta["frames"] if isinstance(frame, dict)]
    if any("camera_model" not in frame and "distortion_params" not in frame for frame in frames):
        faults.extend(_camera_faults(f"{path}", meta))
    for key in DISTORTION_KEYS:
        if key in meta and _number(meta[key]) is None:
            faults.append(f"{path}: {key}={meta[key]!r} is not a finite number. Fix the distortion parameter.")
    colors = meta.get("semantic_colors")
    classes = meta.get("semantic_classes")
    if colors is not None and (
        not isinstance(colors, list) or len(colors) != len(classes or [])
        or any(not isinstance(color, list) or len(color) != 3 for color in colors)
    ):
        faults.append(f"{path}: \"semantic_colors\" must hold one RGB triple per entry of \"semantic_classes\". "
                      "Fix the list or remove it.")
    for key, what in (("depth_file_path", "depth"), ("mask_path", "masks")):
        count = sum(key in frame for frame in frames)
        if 0 < count < len(frames):
            faults.append(
                f"{path}: {count} of {len(frames)} frames list \"{key}\"; nerfstudio needs {what} for every frame or "
                "for none. Add it to the other frames or remove the key."
            )
    names = {_normalised(frame["file_path"]) for frame in frames if isinstance(frame.get("file_path"), str)}
    for split in ("train", "val", "test"):
        listed = meta.get(f"{split}_filenames")
        if listed is None:
            continue
        if not isinstance(listed, list) or not all(isinstance(name, str) for name in listed):
            faults.append(f"{path}: \"{split}_filenames\" must be a list of image paths. Fix it or remove the key.")
            continue
        unknown = [name for name in listed if _normalised(name) not in names]
        if unknown:
            faults.append(
                f"{path}: \"{split}_filenames\" lists {len(unknown)} image(s) no frame has, e.g. {unknown[0]!r}. "
                "List only frames' file_path values."
            )
    return faults


def _normalised(name: str) -> PurePosixPath:
    return PurePosixPath(*[part for part in PurePosixPath(name).parts if part != "."])


def _unknown_model(where: str, model: object) -> str:
    return (f"{where}: camera_model {model!r} is not one nerfstudio supports. Use one of "
            f"{', '.join(sorted(CAMERA_MODEL_TO_TYPE))} (re-run ns-process-data or fix the key).")


def _number(value: object) -> Optional[float]:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    return float(value) if math.isfinite(value) else None


def _frame_faults(where: str, frame: Dict, meta: Dict) -> Tuple[List[str], Optional[Tuple[int, int]]]:
    """Structural faults of one frame, and its camera's (width, height) when that is known."""
    faults = []
    if not isinstance(frame.get("file_path"), str):
        faults.append(f"{where}: no \"file_path\". Give every frame the path of its image.")
    faults.extend(_pose_faults(where, frame.get("transform_matrix")))

    missing, bad = [], []
    values: Dict[str, float] = {}
    for key in INTRINSIC_KEYS:
        raw = frame.get(key, meta.get(key))
        if raw is None:
            missing.append(key)
        elif (number := _number(raw)) is None or number <= 0 or (key in ("w", "h") and number != int(number)):
            bad.append(f"{key}={raw!r}")
        else:
            values[key] = number
    if missing:
        faults.append(f"{where}: no {', '.join(missing)} (neither in the frame nor at the top level). nerfstudio "
                      "needs the intrinsics; add them.")
    if bad:
        faults.append(f"{where}: {', '.join(bad)}: intrinsics must be positive numbers (w and h whole pixels). Fix "
                      "them.")

    if "camera_model" in frame or "distortion_params" in frame:  # (else the top level's camera, checked once)
        faults.extend(_camera_faults(where, {**meta, **frame}))
    for key in DISTORTION_KEYS:
        if key in frame and _number(frame[key]) is None:
            faults.append(f"{where}: {key}={frame[key]!r} is not a finite number. Fix the distortion parameter.")
    size = (int(values["w"]), int(values["h"])) if "w" in values and "h" in values else None
    return faults, size


def _pose_faults(where: str, matrix: object) -> List[str]:
    if matrix is None:
        return [f"{where}: no \"transform_matrix\". Give every frame its 4x4 camera-to-world matrix."]
    try:
        array = np.asarray(matrix, dtype=np.float64)
    except (ValueError, TypeError):
        return [f"{where}: \"transform_matrix\" is not a matrix of numbers (rows of unequal length or non-numbers). "
                "Give a 4x4 camera-to-world matrix."]
    if array.shape == (3, 4):
        return [f"{where}: \"transform_matrix\" is 3x4. Add the last row [0, 0, 0, 1] to make it 4x4."]
    if array.shape != (4, 4):
        return [f"{where}: \"transform_matrix\" has shape {array.shape}. Give a 4x4 camera-to-world matrix."]
    if not np.isfinite(array).all():
        return [f"{where}: \"transform_matrix\" holds NaN or infinite values. Fix this frame's pose (re-run the pose "
                "estimation, e.g. ns-process-data) or remove the frame."]
    return []


def _file_jobs(
    where: str,
    folder: Path,
    frame: Dict,
    size: Optional[Tuple[int, int]],
    num_classes: int,
    contents: bool,
    skip_labels: Collection[str],
) -> List[Callable[[], Optional[str]]]:
    """One check per file the frame lists."""
    jobs: List[Callable[[], Optional[str]]] = []

    def listed(key: str) -> Optional[Path]:
        value = frame.get(key)
        if value is None:
            return None
        if not isinstance(value, str):
            jobs.append(lambda: f"{where}: \"{key}\" is {value!r}, not a path. Give the file's path.")
            return None
        return folder / value

    if (image := listed("file_path")) is not None:
        jobs.append(lambda: _check_image(image, size))
    if (depth := listed("depth_file_path")) is not None:
        jobs.append(lambda: _check_depth(depth, size, contents))
    if (mask := listed("mask_path")) is not None:
        jobs.append(lambda: _check_header(mask, "mask", "mask_path", size))
    for spec in REGISTRY.values():
        if spec.file_key is None or spec.name in skip_labels:
            continue
        if (label := listed(spec.file_key)) is not None:
            jobs.append(lambda spec=spec, label=label: _check_label(spec.name, label, spec.file_key, size, num_classes,
                                                                     contents))
    return jobs


def _not_a_file(path: Path, what: str, key: str) -> Optional[str]:
    if path.is_dir():
        return f"{path}: {what} (\"{key}\") is a folder, not a file. Point the key at the file."
    if not path.is_file():
        return f"{path}: {what} (\"{key}\") does not exist. Add the file or fix the frame's \"{key}\"."
    return None


def _header(path: Path, what: str, key: str) -> Tuple[Optional[Tuple[Tuple[int, int], str]], Optional[str]]:
    """((width, height), PIL mode) from the file's header, or the fault."""
    if (fault := _not_a_file(path, what, key)) is not None:
        return None, fault
    try:
        with Image.open(path) as image:
            return (image.size, image.mode), None
    except (OSError, UnidentifiedImageError, ValueError) as err:
        return None, f"{path}: {what} cannot be decoded ({type(err).__name__}: {err}). Re-export the file."


def _size_fault(path: Path, what: str, found: Tuple[int, int], size: Optional[Tuple[int, int]]) -> Optional[str]:
    if size is None or found == size:
        return None
    return (f"{path}: {what} is {found[0]}x{found[1]} but its frame's camera is {size[0]}x{size[1]}. Resize it, or "
            "give frames of other sizes their own \"w\"/\"h\" (and intrinsics).")


def _check_header(path: Path, what: str, key: str, size: Optional[Tuple[int, int]]) -> Optional[str]:
    header, fault = _header(path, what, key)
    return fault if header is None else _size_fault(path, what, header[0], size)


def _check_image(path: Path, size: Optional[Tuple[int, int]]) -> Optional[str]:
    return _check_header(path, "image", "file_path", size)


def _check_depth(path: Path, size: Optional[Tuple[int, int]], contents: bool) -> Optional[str]:
    """A depth file nerfstudio can read (16/32-bit single-channel image or .npy), of its image's aspect, not all 0."""
    if (fault := _not_a_file(path, "depth map", "depth_file_path")) is not None:
        return fault
    if path.suffix == ".npy":
        try:
            array = np.load(path, mmap_mode="r")
        except (OSError, ValueError) as err:
            return f"{path}: depth .npy cannot be read ({err}). Re-export it."
        if array.dtype.kind not in "fiu" or not (array.ndim == 2 or (array.ndim == 3 and array.shape[2] == 1)):
            return (f"{path}: depth .npy must be an (H, W) array of numbers, got {array.shape} {array.dtype}. "
                    "Re-export it.")
        found = (array.shape[1], array.shape[0])
    else:
        header, fault = _header(path, "depth map", "depth_file_path")
        if header is None:
            return fault
        found, mode = header
        if mode not in DEPTH_MODES:
            return (f"{path}: depth map is a {mode} image; nerfstudio reads depth from a single-channel 16-bit PNG "
                    "(z-depth in millimetres) or a .npy. Point depth_file_path at the depth, or re-export it.")
    if size is not None and abs(found[0] / size[0] - found[1] / size[1]) > 0.02 * found[0] / size[0]:
        return (f"{path}: depth map is {found[0]}x{found[1]}, not the aspect ratio of its camera "
                f"({size[0]}x{size[1]}). "
                "Point depth_file_path at this frame's depth, or resize it.")
    if contents:
        values = np.load(path) if path.suffix == ".npy" else cv2.imread(str(path), cv2.IMREAD_ANYDEPTH)
        if values is None:
            return f"{path}: depth map cannot be decoded. Re-export the file."
        return depth_fault(path, np.asarray(values, dtype=np.float64))
    return None


def depth_fault(path: Path, depth: np.ndarray) -> Optional[str]:
    """The fault of a decoded depth map that has no valid value at all (the dataset checks it as it loads depth)."""
    if (np.isfinite(depth) & (depth > 0)).any():
        return None
    return (f"{path}: depth is zero (or invalid) everywhere. Point depth_file_path at this frame's depth, or remove "
            "the "
            "key from every frame.")


def _check_label(
    name: str, path: Path, key: str, size: Optional[Tuple[int, int]], num_classes: int, contents: bool
) -> Optional[str]:
    """A property label as its registry kind reads it for training (or, without `contents`, its header)."""
    if (fault := _not_a_file(path, f"{name} label", key)) is not None:
        return fault
    if not contents or size is None:
        return _check_header(path, f"{name} label", key, size)
    try:
        REGISTRY[name].kind.read(path, *size, num_classes)
    except LabelFileError as err:
        return str(err)
    return None
