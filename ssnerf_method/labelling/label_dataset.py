"""`ssnerf-label`'s engine: derive property labels for every frame of a posed nerfstudio dataset.

Per frame, each property with a label maker (`PropertySpec.label_maker`, in registry order) either writes a label
image (under `DATA/ssnerf_labels/<property>/`) and sets the frame's file key, keeps a label the frame already lists
(and hands it to the makers after it, as given normals feed shading), or skips with a reason. Semantics are never
derived: they are copied (and converted from colours if need be) from `--semantics-dir`.

A Blender-synthetic folder (no transforms.json, but `transforms_{train,val,test}.json`) is read as nerfstudio's
`blender-data` reads it and gets a new transforms.json. Nothing is written unless every frame succeeds: labels go
through `Staging`, the transforms file is replaced atomically after a one-time backup (`transforms.json.orig`) or
written as a new file.
"""

from __future__ import annotations

import threading
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from copy import deepcopy
from dataclasses import dataclass, field, make_dataclass
from pathlib import Path
from typing import Callable, Dict, List, Optional, Tuple

import numpy as np
import tyro
from typing_extensions import Annotated

from nerfstudio.cameras.cameras import Cameras

from ssnerf_method.data.io import DatasetInputError, Staging, backup_once, read_image, write_json_atomic
from ssnerf_method.data.transforms import Transforms, camera_key, camera_rays, frame_camera, is_perspective
from ssnerf_method.data.validate import validate_dataset, validate_transforms
from ssnerf_method.labelling.paths import label_path, output_path, rebase_paths
from ssnerf_method.labelling.sources import checked_depth, read_class_ids, semantics_file
from ssnerf_method.labels.encoding import SEMANTIC_IGNORE
from ssnerf_method.labels.makers import FrameSources, LabelOptions, Skip
from ssnerf_method.properties import PropertySpec, labelled_properties

LABELLED = "labelled"
KEPT = "kept the label the frame already lists"


@dataclass
class LabelDatasetBase:
    """Write property labels for a nerfstudio dataset (e.g. `ns-process-data` output) and list them in its
    transforms file."""

    data: tyro.conf.Positional[Path]
    """Dataset folder holding transforms.json (or the path of a transforms .json file)."""
    output: Optional[str] = None
    """Write the labelled transforms to this new file instead of updating transforms.json in place (in place, the
    original is first copied to transforms.json.orig, once). A bare name goes in the dataset folder; a path with a
    folder (e.g. a writable copy's `../labelled/transforms.json`) gets the labels beside it and file paths that point
    back at the dataset."""
    label_options: Annotated[LabelOptions, tyro.conf.arg(name="")] = field(default_factory=LabelOptions)
    """The label makers' settings."""
    semantics_dir: Optional[Path] = None
    """Folder of per-frame semantic labels named like the images (same relative path, .png): class ids in an 8/16-bit
    single-channel PNG (255 = unlabelled), or colours listed in transforms.json's semantic_colors."""
    semantic_classes: Optional[List[str]] = None
    """Class names (id = index) for --semantics-dir; default: transforms.json's, else class_0..class_N."""
    relabel: bool = False
    """Recompute labels a frame already lists (default: keep them, e.g. given normals or an outside annotator's)."""
    workers: int = 2
    """Frames labelled in parallel (threads; OpenCV and numpy release the GIL)."""

    def enabled(self, name: str) -> bool:
        """Whether the property's switch is on (`--<name>` / `--no-<name>`)."""
        return bool(getattr(self, name))


LabelDatasetConfig = make_dataclass(
    "LabelDatasetConfig",
    [(spec.name, Annotated[bool, tyro.conf.arg(help=spec.label_maker.help)], field(default=True))
     for spec in labelled_properties()],
    bases=(LabelDatasetBase,),
    namespace={"__doc__": LabelDatasetBase.__doc__, "__module__": __name__},
)
"""`LabelDatasetBase` with one on/off switch per property that has a label maker (all on by default)."""


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


def _check_frames(transforms: Transforms, config: LabelDatasetBase) -> None:
    """Before any work: the dataset passes validation (the labels it keeps included), and label paths are unique."""
    replaced = [spec.name for spec in labelled_properties() if config.enabled(spec.name)] if config.relabel else []
    validate_transforms(transforms.folder, transforms.path, transforms.meta, skip_labels=replaced).raise_if_faulty(
        transforms.folder
    )
    seen: Dict[object, str] = {}
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


def frame_sources(transforms: Transforms, frame: Dict, config: LabelDatasetBase, rays: RayCache) -> FrameSources:
    """What the makers may read of one frame: its image, its camera's rays, and (read when asked) its depth map and
    its annotation in --semantics-dir."""
    rgb = read_image(transforms.file(frame["file_path"]), "image")
    rgb = rgb[..., :3] if rgb.ndim == 3 else np.repeat(rgb[..., None], 3, axis=-1)
    if rgb.dtype != np.uint8:
        rgb = (rgb / 257.0).round().astype(np.uint8)
    camera = frame_camera(transforms, frame)
    height, width = rgb.shape[:2]
    sources = FrameSources(rgb=rgb, rays=lambda scale: rays.get(camera, scale), perspective=is_perspective(camera))
    if "depth_file_path" in frame:
        sources.depth = lambda: checked_depth(transforms.file(frame["depth_file_path"]), width, height)
    if config.semantics_dir is not None:
        folder = config.semantics_dir
        colors = transforms.meta.get("semantic_colors")
        sources.semantics = lambda: read_class_ids(semantics_file(frame, folder), width, height, colors)
    return sources


def label_frame(
    transforms: Transforms, frame: Dict, config: LabelDatasetBase, staging: Staging, rays: RayCache
) -> Tuple[Dict[str, str], Dict[str, str], List[int]]:
    """Label one frame. Returns the keys to set, each property's outcome, and the class ids its labels use."""
    sources = frame_sources(transforms, frame, config, rays)
    height, width = sources.rgb.shape[:2]
    keys, outcomes, class_ids = {}, {}, []
    for spec in labelled_properties():
        enabled = config.enabled(spec.name)
        if spec.file_key in frame and not (enabled and config.relabel):
            if spec.label_maker.provides is not None:
                label = spec.kind.read(transforms.file(frame[spec.file_key]), width, height, 0)
                spec.label_maker.use_label(sources, label.numpy())
            if enabled:
                outcomes[spec.name] = KEPT
            continue
        if not enabled:
            continue
        try:
            image = spec.label_maker.make(sources, config.label_options)
        except Skip as skip:
            outcomes[spec.name] = f"skipped: {skip}"
            continue
        if spec.kind.categorical:
            class_ids += [int(v) for v in np.unique(image) if v != SEMANTIC_IGNORE]
        relative = label_path(frame, spec.name)
        staging.write_png(Path(relative), image)
        keys[spec.file_key] = str(relative)
        outcomes[spec.name] = LABELLED
    return keys, outcomes, class_ids


def label_dataset(
    config: LabelDatasetBase, transforms: Transforms, on_frame: Optional[Callable[[], None]] = None
) -> LabelReport:
    """Label every frame of `transforms` (see the module docstring); all or nothing."""
    output = output_path(config.output, transforms)
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
            class_ids = [class_id for _, _, ids in results for class_id in ids]
            if class_ids:
                meta["semantic_classes"] = _class_names(config, meta, max(class_ids))
            made = [spec for spec in labelled_properties() if report.labelled(spec.name)]
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


def _class_names(config: LabelDatasetBase, meta: Dict, max_id: int) -> List[str]:
    names = config.semantic_classes or meta.get("semantic_classes") or [f"class_{i}" for i in range(max_id + 1)]
    if max_id >= len(names):
        raise DatasetInputError(
            f"{config.semantics_dir}: class id {max_id} but only {len(names)} class names. "
            "Pass every name with --semantic-classes (id = index)."
        )
    return list(names)


def _provenance(config: LabelDatasetBase, made: List[PropertySpec]) -> Dict:
    """What made the labels of `made`, stored in the transforms file so a dataset documents itself."""
    options = LabelOptions(**{**vars(config.label_options), "semantics_from": str(config.semantics_dir)})
    return {"tool": "ssnerf-label", **{spec.name: spec.label_maker.describe(options) for spec in made}}
