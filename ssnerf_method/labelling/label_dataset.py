"""`ssnerf-label`'s engine: derive property labels for every frame of a posed nerfstudio dataset.

Per frame, each enabled labeller either writes a label image (under `DATA/ssnerf_labels/<property>/`) and sets the
frame's `<property>_file_path` key, keeps a label the frame already lists, or skips with a reason:

- edges: Canny on the RGB image;
- keypoints: detector responses (SURF by default) splatted as Gaussians;
- normals: from the frame's depth map (camera frame, OpenGL axes, (n+1)/2; alpha 0 where depth is invalid);
- shading: Lambertian, light at the camera centre, from the frame's normals (given or just derived);
- semantics: never derived; copied (and converted from colours if need be) from `--semantics-dir`.

A Blender-synthetic folder (no transforms.json, but `transforms_{train,val,test}.json`) is read as nerfstudio's
`blender-data` reads it and gets a new transforms.json. Nothing is written unless every frame succeeds: labels go
through `Staging`, the transforms file is replaced atomically after a one-time backup (`transforms.json.orig`) or
written as a new file.
"""

from __future__ import annotations

import os
import threading
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from copy import deepcopy
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import Callable, Dict, List, Optional, Tuple

import cv2
import numpy as np
import tyro

from nerfstudio.cameras.cameras import Cameras

from ssnerf_method.data.io import DatasetInputError, Staging, backup_once, read_image, write_json_atomic
from ssnerf_method.data.transforms import Transforms, camera_key, camera_rays, frame_camera, is_perspective
from ssnerf_method.data.validate import validate_dataset, validate_transforms
from ssnerf_method.labels.edges import canny_edges
from ssnerf_method.labels.encoding import decode_normals, encode_normals, to_uint8
from ssnerf_method.labels.keypoints import Detector, KeypointLabel, describe_keypoint_label, keypoint_label
from ssnerf_method.labels.normals import normals_from_points
from ssnerf_method.labels.shading import shading_from_rays
from ssnerf_method.properties import REGISTRY, SEMANTIC_IGNORE

LABEL_FOLDER = "ssnerf_labels"
"""Folder, inside the dataset, that `ssnerf-label` owns: it only ever writes there (and the transforms file)."""

LABELLED = "labelled"
KEPT = "kept the label the frame already lists"


@dataclass
class LabelDatasetConfig:
    """Write property labels for a nerfstudio dataset (e.g. `ns-process-data` output) and list them in its
    transforms file."""

    data: tyro.conf.Positional[Path]
    """Dataset folder holding transforms.json (or the path of a transforms .json file)."""
    output: Optional[str] = None
    """Write the labelled transforms to this new file instead of updating transforms.json in place (in place, the
    original is first copied to transforms.json.orig, once). A bare name goes in the dataset folder; a path with a
    folder (e.g. a writable copy's `../labelled/transforms.json`) gets the labels beside it and file paths that point
    back at the dataset."""
    edges: bool = True
    """Canny edges of the RGB image."""
    keypoints: bool = True
    """Keypoint heatmap of the RGB image."""
    normals: bool = True
    """Surface normals from each frame's depth map (frames without `depth_file_path` are skipped)."""
    shading: bool = True
    """Lambertian shading from the frame's normals (given or derived)."""
    semantics: bool = True
    """Semantic labels, copied from --semantics-dir (never derived)."""
    canny_low: float = 100.0
    """Canny's lower hysteresis threshold, on the 0-255 grey image's gradient magnitude."""
    canny_high: float = 200.0
    """Canny's upper hysteresis threshold: a gradient above it starts an edge."""
    keypoint_label: KeypointLabel = "response"
    """response: SURF's dense blob-response map (Taskonomy's keypoint2d; a field learns it); blobs: detected keypoints
    splatted as Gaussians (fields render it empty)."""
    keypoint_detector: Detector = "surf"
    """With --keypoint-label blobs: surf, our Fast-Hessian SURF detector (the paper's); sift, orb: OpenCV's."""
    keypoint_sigma: float = 1.5
    """With --keypoint-label blobs: radius (Gaussian standard deviation, pixels) of each splatted keypoint."""
    semantics_dir: Optional[Path] = None
    """Folder of per-frame semantic labels named like the images (same relative path, .png): class ids in an 8/16-bit
    single-channel PNG (255 = unlabelled), or colours listed in transforms.json's semantic_colors."""
    semantic_classes: Optional[List[str]] = None
    """Class names (id = index) for --semantics-dir; default: transforms.json's, else class_0..class_N."""
    relabel: bool = False
    """Recompute labels a frame already lists (default: keep them, e.g. given normals or an outside annotator's)."""
    workers: int = 2
    """Frames labelled in parallel (threads; OpenCV and numpy release the GIL)."""


@dataclass
class FrameContext:
    """What the labellers of one frame share: its image, camera and (once known) its normals."""

    transforms: Transforms
    frame: Dict
    config: LabelDatasetConfig
    rgb: np.ndarray
    rays: Callable[[float], np.ndarray]
    """Unit camera-frame rays of this frame's camera, rescaled by a factor (for depth maps of another size)."""
    perspective: bool
    normals: Optional[np.ndarray] = None
    """(H, W, 3) camera-frame unit normals, NaN where unknown."""
    semantic_ids: List[int] = field(default_factory=list)


class Skip(Exception):
    """A labeller cannot label this frame; the message is the reason shown in the report."""


def _with_alpha(image: np.ndarray, labelled: np.ndarray) -> np.ndarray:
    """Append an alpha channel (0 = unlabelled) when some pixels are unlabelled; else return `image` unchanged."""
    if labelled.all():
        return image
    alpha = np.where(labelled, 255, 0).astype(np.uint8)
    return np.concatenate([image.reshape(*labelled.shape, -1), alpha[..., None]], axis=-1)


def label_edges(context: FrameContext) -> np.ndarray:
    return to_uint8(canny_edges(context.rgb, context.config.canny_low, context.config.canny_high))


def label_keypoints(context: FrameContext) -> np.ndarray:
    config = context.config
    return to_uint8(keypoint_label(context.rgb, config.keypoint_label, config.keypoint_sigma,
                                    config.keypoint_detector))


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


def label_normals(context: FrameContext) -> np.ndarray:
    if "depth_file_path" not in context.frame:
        raise Skip("no depth_file_path")
    if not context.perspective:
        raise Skip("camera model is not a perspective (pinhole) camera")
    depth = read_depth(context.transforms.file(context.frame["depth_file_path"]))
    height, width = context.rgb.shape[:2]
    scale = depth.shape[1] / width
    if abs(depth.shape[0] / height - scale) > 0.02:
        raise DatasetInputError(
            f"{context.transforms.file(context.frame['depth_file_path'])}: depth is {depth.shape[1]}x{depth.shape[0]}, "
            f"not the aspect ratio of its image ({width}x{height}). Fix depth_file_path or resize the depth map."
        )
    rays = context.rays(scale)
    valid = np.isfinite(depth) & (depth > 0)
    points = np.where(valid, depth, 0.0)[..., None] * rays / np.maximum(-rays[..., 2:], 1e-9)
    normals = normals_from_points(points, valid & (rays[..., 2] < 0))
    if depth.shape != (height, width):  # derive at the depth's resolution, then map to image pixels
        normals = cv2.resize(normals, (width, height), interpolation=cv2.INTER_NEAREST)
    context.normals = normals
    labelled = np.isfinite(normals).all(axis=-1)
    return _with_alpha(to_uint8(encode_normals(normals)), labelled)


def use_given_normals(context: FrameContext, path: Path) -> None:
    """Decode the frame's own normals file (for shading)."""
    height, width = context.rgb.shape[:2]
    encoded = REGISTRY["normals"].kind.read(path, width, height, 0).numpy().astype(np.float64)
    normals = decode_normals(encoded)
    context.normals = normals / np.linalg.norm(normals, axis=-1, keepdims=True)


def label_shading(context: FrameContext) -> np.ndarray:
    if context.normals is None:
        raise Skip("no normals (given or derived from depth)")
    shading = shading_from_rays(context.normals, context.rays(1.0))
    return _with_alpha(to_uint8(shading), np.isfinite(shading))


def semantics_source(context: FrameContext) -> Path:
    relative = PurePosixPath(context.frame["file_path"])
    stem = relative.with_suffix(".png")
    candidates = [context.config.semantics_dir / stem, context.config.semantics_dir / stem.name]
    if len(relative.parts) > 1:
        candidates.insert(1, context.config.semantics_dir / PurePosixPath(*relative.parts[1:]).with_suffix(".png"))
    for candidate in candidates:
        if candidate.is_file():
            return candidate
    raise Skip(f"no file in {context.config.semantics_dir}")


def label_semantics(context: FrameContext) -> np.ndarray:
    if context.config.semantics_dir is None:
        raise Skip("not given (semantics are never derived; pass --semantics-dir)")
    path = semantics_source(context)
    labels = read_image(path, "semantic label")
    if labels.shape[:2] != context.rgb.shape[:2]:
        raise DatasetInputError(
            f"{path}: semantic label is {labels.shape[1]}x{labels.shape[0]} but its image is "
            f"{context.rgb.shape[1]}x{context.rgb.shape[0]}. Resize it (nearest neighbour) to the image's size."
        )
    if labels.ndim == 3:
        colors = context.transforms.meta.get("semantic_colors")
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
    context.semantic_ids = sorted(int(v) for v in np.unique(labels) if v != SEMANTIC_IGNORE)
    return labels.astype(np.uint8)


Labeller = Callable[[FrameContext], np.ndarray]

LABELLERS: Dict[str, Tuple[Labeller, Optional[Callable[[FrameContext, Path], None]]]] = {
    "semantics": (label_semantics, None),
    "normals": (label_normals, use_given_normals),
    "shading": (label_shading, None),
    "edges": (label_edges, None),
    "keypoints": (label_keypoints, None),
}
"""Per property, in the order they run (shading needs normals): the labeller and what to do with a given label."""


def label_path(frame: Dict, name: str) -> PurePosixPath:
    """Where a frame's label goes, relative to the dataset: `ssnerf_labels/<name>/<image path>.png`, without the
    image path's leading `images/` (nerfstudio's usual folder); other folders are kept so that names stay unique."""
    parts = [part for part in PurePosixPath(frame["file_path"]).parts if part not in (".", "")]
    if len(parts) > 1 and parts[0] == "images":
        parts = parts[1:]
    return PurePosixPath(LABEL_FOLDER, name, *parts).with_suffix(".png")


@dataclass
class LabelReport:
    """Per property, how many frames ended in each outcome (labelled, kept, or a skip reason)."""

    outcomes: Dict[str, Counter] = field(default_factory=dict)
    transforms_path: Optional[Path] = None
    backup_path: Optional[Path] = None

    def add(self, name: str, outcome: str) -> None:
        self.outcomes.setdefault(name, Counter())[outcome] += 1

    def labelled(self, name: str) -> int:
        return self.outcomes.get(name, Counter())[LABELLED]


def _check_frames(transforms: Transforms, config: LabelDatasetConfig) -> None:
    """Before any work: the dataset passes validation (the labels it keeps included), and label paths are unique."""
    replaced = enabled_properties(config) if config.relabel else []
    validate_transforms(transforms.folder, transforms.path, transforms.meta, skip_labels=replaced).raise_if_faulty(
        transforms.folder
    )
    seen: Dict[PurePosixPath, str] = {}
    for frame in transforms.frames:
        target = label_path(frame, "_")
        if target in seen:
            raise DatasetInputError(
                f"{transforms.path}: frames {seen[target]} and {frame['file_path']} would share label files. "
                "Rename one of the images."
            )
        seen[target] = frame["file_path"]


class RayCache:
    """Camera-frame rays per distinct camera and scale, computed once (nerfstudio's ray generation is not free)."""

    def __init__(self) -> None:
        self._rays: Dict[Tuple, np.ndarray] = {}
        self._lock = threading.Lock()

    def get(self, camera: Cameras, scale: float) -> np.ndarray:
        """Rays of `camera` with its resolution scaled by `scale` (the camera itself is left unchanged)."""
        key = (camera_key(camera), round(scale, 6))
        with self._lock:
            if key not in self._rays:
                scaled = deepcopy(camera)
                if scale != 1.0:
                    scaled.rescale_output_resolution(scale)
                self._rays[key] = camera_rays(scaled)
            return self._rays[key]


def enabled_properties(config: LabelDatasetConfig) -> List[str]:
    return [name for name in LABELLERS if getattr(config, name)]


def label_frame(
    transforms: Transforms, frame: Dict, config: LabelDatasetConfig, staging: Staging, rays: RayCache
) -> Tuple[Dict[str, str], Dict[str, str], List[int]]:
    """Label one frame. Returns the keys to set, each property's outcome, and the semantic ids it uses."""
    rgb = read_image(transforms.file(frame["file_path"]), "image")
    rgb = rgb[..., :3] if rgb.ndim == 3 else np.repeat(rgb[..., None], 3, axis=-1)
    if rgb.dtype != np.uint8:
        rgb = (rgb / 257.0).round().astype(np.uint8)
    camera = frame_camera(transforms, frame)
    context = FrameContext(
        transforms, frame, config, rgb, lambda scale: rays.get(camera, scale), is_perspective(camera),
    )
    keys, outcomes = {}, {}
    for name, (labeller, use_given) in LABELLERS.items():
        file_key = REGISTRY[name].file_key
        enabled = getattr(config, name)
        if file_key in frame and not (enabled and config.relabel):
            if use_given is not None:
                use_given(context, transforms.file(frame[file_key]))
            if enabled:
                outcomes[name] = KEPT
            continue
        if not enabled:
            continue
        try:
            image = labeller(context)
        except Skip as skip:
            outcomes[name] = f"skipped: {skip}"
            continue
        relative = label_path(frame, name)
        staging.write_png(Path(relative), image)
        keys[file_key] = str(relative)
        outcomes[name] = LABELLED
    return keys, outcomes, context.semantic_ids


SPLIT_KEYS = ("train_filenames", "val_filenames", "test_filenames")
"""Top-level transforms keys that list image paths (rewritten with the frames' when the output moves)."""


def output_path(config: LabelDatasetConfig, transforms: Transforms) -> Path:
    """The transforms file `ssnerf-label` writes: the dataset's own, a new name beside it, or a path elsewhere."""
    if config.output is None:
        return transforms.path
    given = Path(config.output)
    return given if given.is_absolute() or given.parent != Path(".") else transforms.folder / given


def rebase_paths(meta: Dict, source: Path, target: Path) -> Dict:
    """A copy of `meta` with every file path of its frames and splits made relative to `target` instead of `source`."""
    if source.resolve() == target.resolve():
        return dict(meta)

    def moved(value: str) -> str:
        return os.path.relpath(source / value, target)

    keys = ["file_path", "depth_file_path", "mask_path",
            *[spec.file_key for spec in REGISTRY.values() if spec.file_key]]
    frames = [{key: moved(value) if key in keys and isinstance(value, str) else value for key, value in frame.items()}
              for frame in meta["frames"]]
    splits = {key: [moved(value) for value in meta[key]] for key in SPLIT_KEYS if key in meta}
    return {**meta, **splits, "frames": frames}


def label_dataset(
    config: LabelDatasetConfig, transforms: Transforms, on_frame: Optional[Callable[[], None]] = None
) -> LabelReport:
    """Label every frame of `transforms` (see the module docstring); all or nothing."""
    output = output_path(config, transforms)
    if config.output is not None and output.exists():
        raise DatasetInputError(f"{output}: exists. Pick a new --output name or remove that file.")
    _check_frames(transforms, config)
    report = LabelReport(transforms_path=output)
    rays = RayCache()
    meta = rebase_paths(transforms.meta, transforms.folder, output.parent)
    try:
        with Staging(output.parent) as staging:
            with ThreadPoolExecutor(max_workers=max(config.workers, 1)) as pool:

                def run(frame: Dict):
                    result = label_frame(transforms, frame, config, staging, rays)
                    if on_frame is not None:
                        on_frame()
                    return result

                results = list(pool.map(run, transforms.frames))

            meta["frames"] = [{**frame, **keys} for frame, (keys, _, _) in zip(meta["frames"], results)]
            for _, outcomes, _ in results:
                for name, outcome in outcomes.items():
                    report.add(name, outcome)
            if report.labelled("semantics"):
                meta["semantic_classes"] = _class_names(config, meta, max(max(ids, default=0) for _, _, ids in results))
            made = [name for name in LABELLERS if report.labelled(name)]
            if made:
                meta["ssnerf_label"] = {**meta.get("ssnerf_label", {}), **_provenance(config, made)}

            staging.commit()
            if config.output is None and transforms.path.exists():  # (a Blender folder has no transforms.json yet)
                report.backup_path = backup_once(transforms.path)
            write_json_atomic(output, meta)
    except PermissionError as err:
        raise DatasetInputError(
            f"{err.filename or output.parent}: cannot write there ({err.strerror}). Nothing was changed; label into a "
            "folder you can write: --output /writable/folder/transforms.json (its file paths point back here)."
        ) from err
    validate_dataset(output).raise_if_faulty(output)  # what ns-train will read (a fault here is a bug of ours)
    return report


def _class_names(config: LabelDatasetConfig, meta: Dict, max_id: int) -> List[str]:
    names = config.semantic_classes or meta.get("semantic_classes") or [f"class_{i}" for i in range(max_id + 1)]
    if max_id >= len(names):
        raise DatasetInputError(
            f"{config.semantics_dir}: class id {max_id} but only {len(names)} class names. "
            "Pass every name with --semantic-classes (id = index)."
        )
    return list(names)


def _provenance(config: LabelDatasetConfig, made: List[str]) -> Dict:
    """What made the labels in `made`, stored in the transforms file so a dataset documents itself."""
    methods = {
        "edges": lambda: f"Canny, thresholds {config.canny_low:g} / {config.canny_high:g} on the 8-bit grey image",
        "keypoints": lambda: describe_keypoint_label(config.keypoint_label, config.keypoint_sigma,
                                                     config.keypoint_detector),
        "normals": lambda: "from depth: camera frame, OpenGL axes (x right, y up, z towards the viewer), "
        "(n + 1) / 2 * 255; alpha 0 where depth is invalid",
        "shading": lambda: "Lambertian, point light at the camera centre: clip(dot(n, -view_dir), 0, 1)",
        "semantics": lambda: f"copied from {config.semantics_dir}",
    }
    return {"tool": "ssnerf-label", **{name: methods[name]() for name in made}}
