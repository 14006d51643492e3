"""`ssnerf-label`'s engine: derive property labels for every frame of a posed nerfstudio dataset.

Per frame, each property's label maker (registry order) writes a label under `DATA/ssnerf_labels/<property>/`, keeps
one the frame lists (feeding later makers), or skips with a reason. Semantics come only from `--annotations` or
`--semantics-dir`; `--depth-from` renders missing depth; a Blender-synthetic folder gets a new transforms.json. All or
nothing: inputs are checked first, labels go through `Staging`, transforms.json is replaced atomically (`.orig` backup).
"""

from __future__ import annotations

import threading
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from copy import deepcopy
from dataclasses import dataclass, field, make_dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Dict, List, Optional, Set, Tuple

import numpy as np
import tyro
from typing_extensions import Annotated

from nerfstudio.cameras.cameras import Cameras

from ssnerf_method.data.io import DatasetInputError, Staging, backup_once, read_image, write_json_atomic
from ssnerf_method.data.transforms import Transforms, camera_key, camera_rays, frame_camera, is_perspective
from ssnerf_method.data.validate import validate_dataset, validate_transforms
from ssnerf_method.importers.annotations import Annotations
from ssnerf_method.label_makers.encoding import SEMANTIC_IGNORE
from ssnerf_method.label_makers.makers import FrameSources, LabelOptions, Skip, Source
from ssnerf_method.label_tool.classes import class_list, class_record
from ssnerf_method.label_tool.paths import label_path, output_path, rebase_paths
from ssnerf_method.label_tool.sources import checked_depth, load_annotations, read_class_ids, semantics_file
from ssnerf_method.properties import PropertySpec, class_property, labelled_properties

if TYPE_CHECKING:  # loading a model imports all of nerfstudio's methods: only with --depth-from
    from ssnerf_method.label_tool.rendered_depth import DepthFromModel

LABELLED = "labelled"
KEPT = "kept the label the frame already lists"


@dataclass
class LabelDatasetBase:
    """Write property labels for a nerfstudio dataset (e.g. `ns-process-data` output) and list them in its
    transforms file."""

    data: tyro.conf.Positional[Path]
    """Dataset folder holding transforms.json (or the path of a transforms .json file)."""
    output: Optional[str] = None
    """Write to this new transforms file instead of in place (which backs up transforms.json.orig once); a bare name
    goes in the dataset folder, a path elsewhere gets the labels beside it and paths back to the dataset."""
    label_options: Annotated[LabelOptions, tyro.conf.arg(name="")] = field(default_factory=LabelOptions)
    """The label makers' settings."""
    annotations: Optional[Path] = None
    """Semantic annotations of any frames, added over their earlier labels (what it labels wins; --relabel: it alone):
    COCO or labelme .json (or a folder of them), answered suggested clicks, or mask PNGs as --semantics-dir. Classes
    match by name; overlaps go to the smaller shape."""
    semantics_dir: Optional[Path] = None
    """Folder of per-frame semantic labels named like the images (same relative path, .png): class ids in an 8/16-bit
    single-channel PNG (255 = unlabelled), or colours listed in transforms.json's semantic_colors."""
    semantic_classes: Optional[List[str]] = None
    """Class names (id = index), written even without labels (e.g. for viewer strokes); fixed for --annotations.
    Default: transforms.json's, then new annotation names (class_0..class_N for --semantics-dir)."""
    depth_from: Optional[Path] = None
    """config.yml of an SS-NeRF trained on this dataset (e.g. a short RGB-only ssnerf-lite): frames without
    depth_file_path get its rendered z-depth, from which normals and shading are made as from sensor depth."""
    depth_model_steps: int = 2000
    """Without --depth-from, frames without depth_file_path (a photo capture) get normals and shading from the depth
    of an RGB-only ssnerf-lite that ssnerf-label trains on the images for this many steps first (kept in
    ssnerf_labels/depth_model/ and reused); 0: those frames get no normals or shading."""
    depth_from_scale: float = 0.25
    """Rendered depth's resolution, as a fraction of each image's (coarser is faster and smooths pixel-scale bumps)."""
    depth_from_smoothing: float = 0.1
    """Average normals from rendered depth over this fraction of the image's shorter side where the image is uniform
    (guided filter, keeping the image's edges); 0: off."""
    suggest_frames: int = 0
    """Instead of labelling: write ssnerf_labels/suggested_frames.json, this many training frames to annotate in
    order, each seeing the most of the scene the earlier ones leave (from the capture's depth, or --load-config's)."""
    suggest_clicks: int = 0
    """Instead of labelling: write ssnerf_labels/suggested_clicks.json, this many training pixels where --load-config's
    model is least sure of the class, apart in 3D; fill in their "class" and import them with --annotations."""
    load_config: Optional[Path] = None
    """config.yml of a model trained on this data, for the suggestions: its rendered depth (and, for clicks, its class
    uncertainty). --suggest-frames without it uses the frames' depth maps."""
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
    notes: List[str] = field(default_factory=list)
    """Lines for the user besides the table (e.g. annotation shapes that were skipped)."""

    def add(self, name: str, outcome: str) -> None:
        self.outcomes.setdefault(name, Counter())[outcome] += 1

    def labelled(self, name: str) -> int:
        return self.outcomes.get(name, Counter())[LABELLED]


def check_frames(transforms: Transforms, config: LabelDatasetBase) -> None:
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


@dataclass
class LabelInputs:
    """What the run reads besides each frame's own files, checked before the first frame is labelled."""

    annotations: Optional[Annotations] = None
    """Shapes per frame from a COCO or labelme source."""
    masks: Optional[Path] = None
    """Folder of per-frame class-id or colour PNGs (--semantics-dir, or --annotations pointing at such a folder)."""
    annotated: Dict[str, Path] = field(default_factory=dict)
    """Frame (file_path) to the file that annotates it, for every frame the annotations or masks cover."""
    replace_annotated: bool = False
    """Whether labels from `annotated` replace a frame's own (--annotations: yes, without --relabel)."""
    classes: Optional[List[str]] = None
    """The class list to write, when known before labelling (annotations, --semantic-classes)."""
    depth_model: Optional[DepthFromModel] = None
    depth_frames: List[str] = field(default_factory=list)
    """Frames whose depth is rendered by `depth_model`."""

    def given(self, frame: Dict) -> Set[Source]:
        """Sources given explicitly for this frame, whose labels replace the frame's own."""
        return {"semantics"} if self.replace_annotated and frame["file_path"] in self.annotated else set()

    def source_format(self) -> Optional[str]:
        if self.annotations is not None:
            return self.annotations.format
        return "masks" if self.masks is not None else None


def _depth_readers() -> List[PropertySpec]:
    return [spec for spec in labelled_properties() if "depth" in spec.label_maker.reads]


def frames_needing_depth(config: LabelDatasetBase, transforms: Transforms, model: bool = False) -> List[str]:
    """File paths of the frames --depth-from renders: no depth_file_path, and a depth-reading maker will run (with
    `model`, whether or not a --depth-from model is given yet)."""
    if config.depth_from is None and not model:
        return []
    return [frame["file_path"] for frame in transforms.frames if "depth_file_path" not in frame and any(
        config.enabled(spec.name) and (spec.file_key not in frame or config.relabel) for spec in _depth_readers())]


def prepare_inputs(config: LabelDatasetBase, transforms: Transforms) -> LabelInputs:
    """Read and check --annotations, --semantic-classes and --depth-from (the model only if some frame needs it)."""
    inputs = LabelInputs(masks=config.semantics_dir, classes=list(config.semantic_classes or []) or None)
    if config.label_options.semantics_grow < 0:
        raise DatasetInputError(f"--semantics-grow {config.label_options.semantics_grow:g}: must be 0 (off) or more. "
                                "Pass e.g. 300 (larger grows clicks over larger segments).")
    if config.annotations is not None:
        if config.semantics_dir is not None:
            raise DatasetInputError(f"{config.annotations}: --annotations and --semantics-dir both given. Pass one "
                                    "(--annotations also reads a folder of mask PNGs).")
        if not config.enabled("semantics"):
            raise DatasetInputError(f"{config.annotations}: --annotations with --no-semantics labels nothing. Drop "
                                    "one of them.")
        inputs.annotations = load_annotations(config.annotations, transforms)
        inputs.replace_annotated = True
        if inputs.annotations is None:
            inputs.masks = config.annotations
        else:
            source = inputs.annotations
            inputs.annotated = {path: frame.source for path, frame in source.frames.items()}
            inputs.classes = class_list(transforms.meta.get("semantic_classes") or [], config.semantic_classes,
                                        source.used_labels(), source.source, declared=source.labels)
    if inputs.masks is not None:
        inputs.annotated = {frame["file_path"]: path for frame in transforms.frames
                            if (path := _mask_file(frame, inputs.masks)) is not None}
    if config.depth_from is not None:
        from ssnerf_method.label_tool.rendered_depth import checked_config, load_depth_model

        if not 0.0 < config.depth_from_scale <= 1.0:
            raise DatasetInputError(f"--depth-from-scale {config.depth_from_scale:g}: must be in (0, 1]. Pass e.g. "
                                    "0.5 (half the image resolution).")
        if not 0.0 <= config.depth_from_smoothing < 1.0:
            raise DatasetInputError(f"--depth-from-smoothing {config.depth_from_smoothing:g}: must be in [0, 1). Pass "
                                    "e.g. 0.1 (a tenth of the image's shorter side), or 0 for none.")
        checked_config(config.depth_from)
        inputs.depth_frames = frames_needing_depth(config, transforms)
        if inputs.depth_frames:
            inputs.depth_model = load_depth_model(config.depth_from, transforms)
    return inputs


def frame_sources(
    transforms: Transforms, frame: Dict, config: LabelDatasetBase, rays: RayCache, inputs: LabelInputs,
    on_depth: Optional[Callable[[], None]] = None,
) -> FrameSources:
    """What the makers may read of one frame: image, rays, and (lazily) depth (or --depth-from's) and annotation."""
    rgb = read_image(transforms.file(frame["file_path"]), "image")
    rgb = rgb[..., :3] if rgb.ndim == 3 else np.repeat(rgb[..., None], 3, axis=-1)
    if rgb.dtype != np.uint8:
        rgb = (rgb / 257.0).round().astype(np.uint8)
    camera = frame_camera(transforms, frame)
    height, width = rgb.shape[:2]
    sources = FrameSources(rgb=rgb, rays=lambda scale: rays.get(camera, scale), perspective=is_perspective(camera))
    if "depth_file_path" in frame:
        sources.depth = lambda: checked_depth(transforms.file(frame["depth_file_path"]), width, height)
    elif inputs.depth_model is not None and frame["file_path"] in inputs.depth_frames:
        model = inputs.depth_model

        def rendered() -> np.ndarray:
            depth = model.z_depth(transforms, frame, config.depth_from_scale)
            if on_depth is not None:
                on_depth()
            return depth

        sources.depth = rendered
        sources.normals_smoothing = round(config.depth_from_smoothing * min(width, height))
    if inputs.annotations is not None:
        annotations, classes = inputs.annotations, inputs.classes or []
        if frame["file_path"] in annotations.frames:
            sources.semantics = lambda: over_earlier(
                annotations.class_ids(frame["file_path"], classes, height, width), transforms, frame, config)
        else:
            sources.semantics = lambda: _not_annotated(annotations.source)
    elif inputs.masks is not None:
        folder = inputs.masks
        colors = transforms.meta.get("semantic_colors")
        sources.semantics = lambda: over_earlier(
            read_class_ids(semantics_file(frame, folder), width, height, colors), transforms, frame, config)
    return sources


def over_earlier(class_ids: np.ndarray, transforms: Transforms, frame: Dict, config: LabelDatasetBase) -> np.ndarray:
    """An import's class ids over the frame's earlier semantics: what it labels wins, the rest keeps the earlier
    label (each import adds to the data); with --relabel, the import alone."""
    key = class_property().file_key
    if config.relabel or key not in frame:
        return class_ids
    height, width = class_ids.shape
    earlier = read_class_ids(transforms.file(frame[key]), width, height, None)
    return np.where(class_ids != SEMANTIC_IGNORE, class_ids, earlier).astype(class_ids.dtype)


def _not_annotated(source: Path) -> np.ndarray:
    raise Skip(f"no annotation in {source}")


def _mask_file(frame: Dict, folder: Path) -> Optional[Path]:
    try:
        return semantics_file(frame, folder)
    except Skip:
        return None


def label_frame(
    transforms: Transforms, frame: Dict, config: LabelDatasetBase, staging: Staging, rays: RayCache,
    inputs: LabelInputs, on_depth: Optional[Callable[[], None]] = None,
) -> Tuple[Dict[str, str], Dict[str, str], List[int]]:
    """Label one frame: the keys to set, each outcome, the class ids used (`LabelInputs.given` sources replace)."""
    sources = frame_sources(transforms, frame, config, rays, inputs, on_depth)
    given = inputs.given(frame)
    height, width = sources.rgb.shape[:2]
    keys, outcomes, class_ids = {}, {}, []
    for spec in labelled_properties():
        enabled = config.enabled(spec.name)
        replace = config.relabel or any(source in given for source in spec.label_maker.reads)
        if spec.file_key in frame and not (enabled and replace):
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
    config: LabelDatasetBase, transforms: Transforms, on_frame: Optional[Callable[[], None]] = None,
    on_depth: Optional[Callable[[], None]] = None,
) -> LabelReport:
    """Label every frame of `transforms`, all or nothing; `on_frame` / `on_depth` report progress."""
    output = output_path(config.output, transforms)
    if config.output is not None and output.exists():
        raise DatasetInputError(f"{output}: exists. Pick a new --output name or remove that file.")
    check_frames(transforms, config)
    inputs = prepare_inputs(config, transforms)
    report = LabelReport(transforms_path=output)
    if inputs.annotations is not None and inputs.annotations.skipped:
        skipped = ", ".join(f"{count} {kind}" for kind, count in sorted(inputs.annotations.skipped.items()))
        report.notes.append(f"{inputs.annotations.source}: skipped shapes that label no pixels ({skipped}).")
    rays = RayCache()
    meta = rebase_paths(transforms.meta, transforms.folder, output.parent)
    try:
        with Staging(output.parent) as staging:
            with ThreadPoolExecutor(max_workers=max(config.workers, 1)) as pool:

                def run(frame: Dict):
                    result = label_frame(transforms, frame, config, staging, rays, inputs, on_depth)
                    if on_frame is not None:
                        on_frame()
                    return result

                results = list(pool.map(run, transforms.frames))

            meta["frames"] = [{**frame, **keys} for frame, (keys, _, _) in zip(meta["frames"], results)]
            for _, outcomes, _ in results:
                for name, outcome in outcomes.items():
                    report.add(name, outcome)
            class_ids = [class_id for _, _, ids in results for class_id in ids]
            names = inputs.classes
            if class_ids:
                names = _class_names(config, names or meta.get("semantic_classes"), max(class_ids))
            if names is not None:
                meta.update(class_record(meta, names))
            made = [spec for spec in labelled_properties() if report.labelled(spec.name)]
            made_from: Dict[Source, Set[str]] = {}  # the frames labelled from each source, as the output lists them
            for frame, (_, outcomes, _) in zip(meta["frames"], results):
                for spec in made:
                    if outcomes.get(spec.name) == LABELLED:
                        for source in spec.label_maker.reads:
                            made_from.setdefault(source, set()).add(frame["file_path"])
            if made:
                written = {frame["file_path"]: output_frame["file_path"]
                           for frame, output_frame in zip(transforms.frames, meta["frames"])}
                meta["ssnerf_label"] = _provenance(config, made, inputs, made_from, written,
                                                   meta.get("ssnerf_label", {}))

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


def _class_names(config: LabelDatasetBase, names: Optional[List[str]], max_id: int) -> List[str]:
    names = names or [f"class_{i}" for i in range(max_id + 1)]
    if max_id >= len(names):
        raise DatasetInputError(
            f"{config.annotations or config.semantics_dir}: class id {max_id} but only {len(names)} class names. "
            "Pass every name with --semantic-classes (id = index)."
        )
    return list(names)


SOURCE_RECORDS: Dict[Source, str] = {"semantics": "annotations", "depth": "depth_from"}
"""The provenance key that says where a frame source came from, for the sources an input can give."""


def _source_records(
    config: LabelDatasetBase, inputs: LabelInputs, made: Dict[Source, Set[str]], written: Dict[str, str],
    earlier_imports: List[Dict],
) -> Dict[str, Any]:
    """Where this run's annotations and rendered depth came from, per frame as the output names it (`written`): the
    annotation imports as a list, this one after the `earlier_imports` (which --relabel drops)."""
    records: Dict[str, Any] = {}
    source = inputs.annotations.source if inputs.annotations is not None else inputs.masks
    if source is not None and made.get("semantics"):
        record = {
            "source": str(source.resolve()), "format": inputs.source_format(),
            "frames": {written[path]: str(file.resolve()) for path, file in inputs.annotated.items()
                       if written[path] in made["semantics"]},
        }
        if inputs.annotations is not None and inputs.annotations.skipped:
            record["skipped_shapes"] = dict(inputs.annotations.skipped)
        records["annotations"] = [*([] if config.relabel else earlier_imports), record]
    rendered = [written[path] for path in inputs.depth_frames if written[path] in made.get("depth", set())]
    if inputs.depth_model is not None and rendered:
        records["depth_from"] = {**inputs.depth_model.describe(config.depth_from_scale),
                                 "smoothing": config.depth_from_smoothing, "frames": rendered}
    return records


def _provenance(
    config: LabelDatasetBase, made: List[PropertySpec], inputs: LabelInputs, made_from: Dict[Source, Set[str]],
    written: Dict[str, str], earlier: Dict,
) -> Dict:
    """What made the labels of `made`, stored in the transforms file so a dataset documents itself: merged over the
    `earlier` record, whose record of a source (annotations, rendered depth) goes when labels from it are remade."""
    semantics_from = str(inputs.masks)
    if inputs.annotations is not None:
        semantics_from = f"{inputs.annotations.source} ({inputs.annotations.format}, rasterised by pycocotools)"
    options = LabelOptions(**{**vars(config.label_options), "semantics_from": semantics_from})
    remade = {SOURCE_RECORDS[source] for source in made_from if source in SOURCE_RECORDS}
    record = {key: value for key, value in earlier.items() if key not in remade}
    record.update({"tool": "ssnerf-label", **{spec.name: spec.label_maker.describe(options) for spec in made}})
    imports = earlier.get("annotations", [])
    imports = [imports] if isinstance(imports, dict) else list(imports)  # (one record, before imports were listed)
    record.update(_source_records(config, inputs, made_from, written, imports))
    return record
