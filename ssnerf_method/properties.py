"""The property registry: the one place that says what each rendered scene property is.

Every other module reads a `PropertySpec` from `REGISTRY` instead of naming properties itself: a `kind` (storage,
activation, rendering, validity, display) plus the paper's branch, loss, weight and metric. A new property is one entry.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Dict, List, Literal, Optional, Sequence, Tuple

import numpy as np
import torch
import torch.nn.functional as F
from jaxtyping import Bool, Float
from PIL import Image
from torch import Tensor

from nerfstudio.model_components.renderers import NormalsRenderer, RGBRenderer, SemanticRenderer
from nerfstudio.utils import colormaps

from ssnerf_method.errors import UserError
from ssnerf_method.label_makers.encoding import SEMANTIC_IGNORE, decode_normals, encode_normals
from ssnerf_method.label_makers.makers import (
    CannyEdges,
    KeypointMap,
    LabelMaker,
    LambertianShading,
    NormalsFromDepth,
    SemanticsCopy,
)

Branch = Literal["v", "nv"]
"""Decoder branch: `v` sees the view direction (F_dec^v), `nv` does not (F_dec^nv)."""

LossName = Literal["mse", "l1", "cross_entropy"]
"""Names of the losses in `ssnerf_method/model/losses.py`."""


NORMAL_LENGTH_TOLERANCE = 0.1
"""A labelled normal is a unit vector when its decoded length is within this of 1 (8-bit rounding moves it < 0.01)."""
MAX_NON_UNIT_FRACTION = 0.05
"""Largest share of a normals label's pixels off unit length (anti-aliased edges and resizing shorten a few)."""


UNNAMED_LOGIT = -1e4
"""Rendered logit of an unnamed spare class slot: never the argmax, finite so a softmax stays defined."""


class LabelFileError(UserError, ValueError):
    """A property file that cannot be used for training; the message names the file and the fix."""


@dataclass
class RenderContext:
    """What a kind may need besides samples and weights to turn them into a pixel value."""

    background_color: Optional[Tensor] = None
    """Background colour for RGB compositing (nerfstudio's `RGBRenderer` semantics)."""
    world_to_camera: Optional[Float[Tensor, "*bs 3 3"]] = None
    """Rotation taking world vectors into each ray's camera frame (OpenGL axes)."""


def _read_image(path: Path) -> np.ndarray:
    """Read a PNG as stored (no mode conversion), with one clear error if it is missing or unreadable."""
    if path.is_dir():
        raise LabelFileError(f"{path}: listed in transforms.json as a label file but is a folder. Point the key at "
                             "the frame's label image.")
    if not path.is_file():
        raise LabelFileError(f"{path}: file listed in transforms.json does not exist. Add the file or remove its key.")
    try:
        with Image.open(path) as image:
            image.load()
            return np.asarray(image)
    except (OSError, ValueError) as err:
        raise LabelFileError(f"{path}: cannot be read as an image ({err}). Re-export it as a PNG.") from err


def _read_uint8(
    path: Path, width: int, height: int, channels: int, content: str, alpha: bool = False
) -> Tuple[np.ndarray, np.ndarray]:
    """An 8-bit label PNG's values checked against the camera, and its labelled mask (with `alpha`: alpha > 0)."""
    array = _read_image(path)
    if array.shape[:2] != (height, width):
        raise LabelFileError(
            f"{path}: image is {array.shape[1]}x{array.shape[0]} but its frame's camera is {width}x{height}. "
            "Resize the label to the RGB image's size."
        )
    found = 1 if array.ndim == 2 else array.shape[2]
    allowed = (channels, channels + 1) if alpha else (channels,)
    if found not in allowed or array.dtype != np.uint8:
        mode = "single-channel (mode 'L')" if channels == 1 else "RGB"
        if alpha:
            mode += " or " + ("grey+alpha (mode 'LA')" if channels == 1 else "RGBA")
        raise LabelFileError(
            f"{path}: {content} must be an 8-bit {mode} PNG, got shape {array.shape} {array.dtype}. "
            f"Save it as an 8-bit {mode} PNG."
        )
    if found == channels:
        return array, np.ones((height, width), dtype=bool)
    values = array[..., 0] if channels == 1 else array[..., :channels]
    return values, array[..., channels] > 0


class PropertyKind(ABC):
    """How one kind of property is stored, predicted per sample, rendered, validated and displayed."""

    ignore_value: float = float("nan")
    """Label value meaning "no label here" in the training batch."""
    prediction_suffix: str = ""
    """Suffix of the model output holding the rendered prediction when it is not itself display-ready."""
    categorical: bool = False
    """Values are class ids: resized with nearest neighbours, never interpolated."""
    needs_pose: bool = False
    """The field's decoder takes each ray's encoded camera pose as an input (the paper's normal modelling)."""

    @abstractmethod
    def head_channels(self, num_classes: int) -> int:
        """Channels the field head predicts per sample."""

    def per_pixel(self) -> "PropertyKind":
        """The kind as a network predicting each pixel of an image (the Hybrid's annotators) predicts it."""
        return self

    def label_channels(self, num_classes: int) -> int:
        """Channels of the label tensor in the batch (defaults to the head's)."""
        return self.head_channels(num_classes)

    def activation(self, raw: Float[Tensor, "*bs channels"]) -> Float[Tensor, "*bs channels"]:
        """Per-sample activation applied to the head's raw output."""
        return raw

    def render(
        self, values: Float[Tensor, "*bs num_samples channels"], weights: Float[Tensor, "*bs num_samples 1"],
        context: RenderContext,
    ) -> Float[Tensor, "*bs channels"]:
        """Volume-render per-sample values into the per-ray prediction the loss compares with the label."""
        return SemanticRenderer()(values, weights)

    def valid(self, label: Float[Tensor, "*bs channels"]) -> Bool[Tensor, " *bs"]:
        """Boolean mask of rays whose label exists."""
        return ~torch.isnan(label).any(dim=-1)

    def read(self, path: Path, width: int, height: int, num_classes: int) -> Float[Tensor, "height width channels"]:
        """Read and validate a label file."""
        raise NotImplementedError(f"{type(self).__name__} has no label file")

    def missing(self, width: int, height: int, num_classes: int) -> Float[Tensor, "height width channels"]:
        """Label tensor for a frame that lacks this property: every pixel ignored."""
        return torch.full((height, width, self.label_channels(num_classes)), self.ignore_value)

    @abstractmethod
    def display(
        self, prediction: Float[Tensor, "*bs channels"], palette: Optional[Float[Tensor, "classes 3"]] = None
    ) -> Float[Tensor, "*bs out"]:
        """Display-ready image: 3-channel colours or a 1-channel float in [0, 1]."""

    def label_as_prediction(self, label: Float[Tensor, "*bs channels"], num_classes: int) -> Float[Tensor, "*bs out"]:
        """A label in the rendered prediction's layout (for display), unlabelled pixels zeroed."""
        return torch.nan_to_num(label, nan=0.0)

    def encode(self, prediction: Float[Tensor, "height width channels"]) -> np.ndarray:
        """A prediction as this kind's label file content (what `read` reads back): uint8 (H, W) or (H, W, 3)."""
        values = torch.nan_to_num(prediction.detach().float(), nan=0.0).clamp(0.0, 1.0).cpu().numpy()
        encoded = np.round(values * 255.0).astype(np.uint8)
        return encoded[..., 0] if encoded.shape[-1] == 1 else encoded

    def reframe(
        self, label: Float[Tensor, "*bs channels"], rotation: Float[Tensor, "3 3"]
    ) -> Float[Tensor, "*bs channels"]:
        """A label moved to a camera whose frame is `rotation` @ this one's; unchanged unless camera-frame vectors."""
        return label

    def export_outputs(
        self, name: str, prediction: Float[Tensor, "*bs channels"], context: RenderContext
    ) -> Dict[str, Tensor]:
        """Extra per-ray outputs for nerfstudio's exporters (`ns-export`), rendered in eval mode only; none here."""
        return {}

    def display_extras(self, name: str) -> List[str]:
        """Keys of `export_outputs` to show besides `name` (viewer, `ns-render`); none by default."""
        return []

    def point_values(self, name: str, outputs: Dict[str, Tensor]) -> Dict[str, Tensor]:
        """Per-ray values for a point cloud, by PLY property name: one float per channel (`name` or `name_0`, ...)."""
        prediction = outputs[name + self.prediction_suffix].float()
        if prediction.shape[-1] == 1:
            return {name: prediction[..., 0]}
        return {f"{name}_{channel}": prediction[..., channel] for channel in range(prediction.shape[-1])}


class ColorKind(PropertyKind):
    """RGB radiance: sigmoid per sample, composited over the background by nerfstudio's `RGBRenderer`."""

    def head_channels(self, num_classes: int) -> int:
        return 3

    def activation(self, raw: Float[Tensor, "*bs channels"]) -> Float[Tensor, "*bs channels"]:
        return torch.sigmoid(raw)

    def render(
        self, values: Float[Tensor, "*bs num_samples channels"], weights: Float[Tensor, "*bs num_samples 1"],
        context: RenderContext,
    ) -> Float[Tensor, "*bs channels"]:
        background = "last_sample" if context.background_color is None else context.background_color
        return RGBRenderer(background_color=background)(values, weights)

    def display(
        self, prediction: Float[Tensor, "*bs channels"], palette: Optional[Float[Tensor, "classes 3"]] = None
    ) -> Float[Tensor, "*bs out"]:
        return prediction.clamp(0.0, 1.0)

    def point_values(self, name: str, outputs: Dict[str, Tensor]) -> Dict[str, Tensor]:
        """8-bit `red`, `green`, `blue`, as point-cloud viewers expect."""
        colours = (outputs[name].clamp(0.0, 1.0) * 255.0).round().to(torch.uint8)
        return dict(zip(("red", "green", "blue"), colours.unbind(-1)))


def class_uncertainty(logits: Float[Tensor, "*bs classes"]) -> Float[Tensor, "*bs 1"]:
    """Class entropy over its maximum (named classes only, not `UNNAMED_LOGIT`): 0 certain, 1 all equally likely."""
    logits = logits.float()
    named = (logits > UNNAMED_LOGIT / 2).sum(dim=-1, keepdim=True).clamp(min=2)
    log_probabilities = torch.log_softmax(logits, dim=-1)
    entropy = -(log_probabilities.exp() * log_probabilities).sum(dim=-1, keepdim=True)
    return (entropy / torch.log(named.to(entropy))).clamp(0.0, 1.0)


class ClassKind(PropertyKind):
    """Semantic labels: logits per sample, volume-rendered as logits, softmax after rendering (paper Sec. 3.3)."""

    ignore_value = float(SEMANTIC_IGNORE)
    prediction_suffix = "_logits"
    categorical = True

    def head_channels(self, num_classes: int) -> int:
        return num_classes

    def label_channels(self, num_classes: int) -> int:
        return 1

    def valid(self, label: Float[Tensor, "*bs channels"]) -> Bool[Tensor, " *bs"]:
        return label[..., 0] != SEMANTIC_IGNORE

    def read(self, path: Path, width: int, height: int, num_classes: int) -> Float[Tensor, "height width channels"]:
        array, _ = _read_uint8(path, width, height, 1, "semantics (class ids)")
        bad = np.unique(array[(array >= num_classes) & (array != SEMANTIC_IGNORE)])
        if bad.size:
            raise LabelFileError(
                f"{path}: class ids {bad.tolist()} are outside semantic_classes (0..{num_classes - 1}; "
                f"{SEMANTIC_IGNORE} = unlabelled). Add the classes to transforms.json or relabel the pixels."
            )
        return torch.from_numpy(array.astype(np.float32))[..., None]

    def display(
        self, prediction: Float[Tensor, "*bs channels"], palette: Optional[Float[Tensor, "classes 3"]] = None
    ) -> Float[Tensor, "*bs out"]:
        assert palette is not None, "semantic display needs a class palette"
        return palette.to(prediction.device)[prediction.argmax(dim=-1)]

    def label_as_prediction(self, label: Float[Tensor, "*bs channels"], num_classes: int) -> Float[Tensor, "*bs out"]:
        ids = label[..., 0].long().clamp(max=num_classes - 1) * self.valid(label)
        return F.one_hot(ids, num_classes).float()

    def encode(self, prediction: Float[Tensor, "height width channels"]) -> np.ndarray:
        """The most likely class id per pixel, (H, W) uint8."""
        return prediction.argmax(dim=-1).cpu().numpy().astype(np.uint8)

    def export_outputs(
        self, name: str, prediction: Float[Tensor, "*bs channels"], context: RenderContext
    ) -> Dict[str, Tensor]:
        """`<name>_uncertainty` (`class_uncertainty`): high where no label settled the class (strokes help there)."""
        return {f"{name}_uncertainty": class_uncertainty(prediction)}

    def display_extras(self, name: str) -> List[str]:
        """The uncertainty is shown in the viewer: paint strokes where it is bright."""
        return [f"{name}_uncertainty"]

    def point_values(self, name: str, outputs: Dict[str, Tensor]) -> Dict[str, Tensor]:
        """The most likely class id (uint8; the names go in the PLY header) and its uncertainty (float)."""
        return {name: outputs[name + self.prediction_suffix].argmax(dim=-1).to(torch.uint8),
                f"{name}_uncertainty": outputs[f"{name}_uncertainty"][..., 0].float()}


class NormalKind(PropertyKind):
    """Surface normals in the camera frame as (n+1)/2: `world` mode (default) renders world vectors and rotates them
    per ray; `pose` mode (the paper's) has a pose-conditioned decoder predict the camera-frame encoding (sigmoid)."""

    def __init__(self, mode: Literal["world", "pose"] = "world") -> None:
        self.mode = mode
        self.needs_pose = mode == "pose"

    def per_pixel(self) -> "NormalKind":
        """An image network predicts the camera-frame encoding directly, as the pose mode does."""
        return NormalKind("pose")

    def head_channels(self, num_classes: int) -> int:
        return 3

    def activation(self, raw: Float[Tensor, "*bs channels"]) -> Float[Tensor, "*bs channels"]:
        return torch.sigmoid(raw) if self.mode == "pose" else raw

    def render(
        self, values: Float[Tensor, "*bs num_samples channels"], weights: Float[Tensor, "*bs num_samples 1"],
        context: RenderContext,
    ) -> Float[Tensor, "*bs channels"]:
        if self.mode == "pose":
            return SemanticRenderer()(values, weights)
        normals = NormalsRenderer()(values, weights, normalize=True)
        if context.world_to_camera is not None:  # (rays without a camera, e.g. ns-export's probe, stay in world axes)
            normals = torch.einsum("...ij,...j->...i", context.world_to_camera, normals)
        return encode_normals(F.normalize(normals, dim=-1))

    def export_outputs(
        self, name: str, prediction: Float[Tensor, "*bs channels"], context: RenderContext
    ) -> Dict[str, Tensor]:
        """`<name>_world`: the world-frame unit normal as (n+1)/2, what `ns-export --normal-output-name` takes."""
        normals = decode_normals(prediction)
        if context.world_to_camera is not None:
            normals = torch.einsum("...ji,...j->...i", context.world_to_camera, normals)
        return {f"{name}_world": encode_normals(F.normalize(normals, dim=-1)).clamp(0.0, 1.0)}

    def point_values(self, name: str, outputs: Dict[str, Tensor]) -> Dict[str, Tensor]:
        """The world-frame unit normal as `nx`, `ny`, `nz` (the PLY convention)."""
        normals = decode_normals(outputs[f"{name}_world"].float())
        return dict(zip(("nx", "ny", "nz"), normals.unbind(-1)))

    def reframe(
        self, label: Float[Tensor, "*bs channels"], rotation: Float[Tensor, "3 3"]
    ) -> Float[Tensor, "*bs channels"]:
        normals = torch.einsum("ij,...j->...i", rotation.to(label), decode_normals(label))
        return encode_normals(normals)

    def read(self, path: Path, width: int, height: int, num_classes: int) -> Float[Tensor, "height width channels"]:
        array, labelled = _read_uint8(path, width, height, 3, "normals ((n+1)/2 per channel)", alpha=True)
        values = array.astype(np.float32) / 255.0
        lengths = np.linalg.norm(decode_normals(values[labelled]), axis=-1)
        off = float(np.mean(np.abs(lengths - 1.0) > NORMAL_LENGTH_TOLERANCE)) if lengths.size else 0.0
        if off > MAX_NON_UNIT_FRACTION:
            raise LabelFileError(
                f"{path}: {off:.0%} of the labelled pixels are not unit normals (an all-zero image decodes to "
                "(-1, -1, -1)). Store unit camera-frame normals n as (n + 1) / 2 * 255, alpha 0 where there is none."
            )
        values[~labelled] = np.nan
        return torch.from_numpy(values)

    def display(
        self, prediction: Float[Tensor, "*bs channels"], palette: Optional[Float[Tensor, "classes 3"]] = None
    ) -> Float[Tensor, "*bs out"]:
        return prediction.clamp(0.0, 1.0)


class ScalarKind(PropertyKind):
    """A [0, 1] map (shading, keypoints, edges) as an 8-bit grey PNG, value/255; rendered under `<name>_value`."""

    prediction_suffix = "_value"

    def __init__(self, activation: Literal["sigmoid", "relu"]) -> None:
        self.activation_name = activation

    def head_channels(self, num_classes: int) -> int:
        return 1

    def activation(self, raw: Float[Tensor, "*bs channels"]) -> Float[Tensor, "*bs channels"]:
        return torch.sigmoid(raw) if self.activation_name == "sigmoid" else torch.relu(raw)

    def read(self, path: Path, width: int, height: int, num_classes: int) -> Float[Tensor, "height width channels"]:
        array, labelled = _read_uint8(path, width, height, 1, "this map (value/255 in [0, 1])", alpha=True)
        values = array.astype(np.float32) / 255.0
        values[~labelled] = np.nan
        return torch.from_numpy(values)[..., None]

    def display(
        self, prediction: Float[Tensor, "*bs channels"], palette: Optional[Float[Tensor, "classes 3"]] = None
    ) -> Float[Tensor, "*bs out"]:
        return prediction.clamp(0.0, 1.0)


@dataclass(frozen=True)
class PropertySpec:
    """One rendered property and the paper's choices for it."""

    name: str
    """Output name in the model, the viewer and `ns-render`; also the batch key of its label."""
    short: str
    """The paper's abbreviation."""
    kind: PropertyKind
    file_key: Optional[str]
    """Per-frame key of its label file in transforms.json (None: nerfstudio loads it, as for RGB)."""
    branch: Branch
    """Decoder branch in the paper's final model."""
    loss: LossName
    """Loss name, implemented in `ssnerf_method/model/losses.py`."""
    weight: float
    """Loss weight lambda (paper Sec. 4.1)."""
    metric: Literal["psnr", "miou", "l1", "normal", "edge", "keypoint"]
    """Evaluation metric, implemented in `ssnerf_method/evaluation/metrics.py`."""
    colormap: str
    """Display colour mapping of a one-channel map (a nerfstudio colormap name); "default" for images in colour."""
    corruption: Literal["classes", "dense", "sparse", "none"] = "none"
    """How weak labels of it are made for the auto-labelling study (`labels/corruptions.py`)."""
    label_maker: Optional[LabelMaker] = None
    """How its label is made from a frame (`labels/makers.py`): by `ssnerf-label` and by the scene generator."""

    @property
    def prediction_key(self) -> str:
        """Model output compared with the label (the display image lives under `name`)."""
        return self.name + self.kind.prediction_suffix

    def display(self, prediction: Tensor, palette: Optional[Tensor] = None) -> Float[Tensor, "*bs 3"]:
        """The image people see; a one-channel map goes through `colormap` over a fixed [0, 1] so frames compare."""
        shown = self.kind.display(prediction, palette)
        if shown.shape[-1] != 1:
            return shown
        values = torch.nan_to_num(shown, nan=0.0).clamp(0.0, 1.0)
        if self.colormap == "gray":  # nerfstudio's grey path assumes (H, W, 1); rays come as (N, 1)
            return values.expand(*values.shape[:-1], 3)
        return colormaps.apply_float_colormap(values, colormap=self.colormap)  # type: ignore[arg-type]

    @property
    def label_key(self) -> str:
        """Batch key of the label: nerfstudio's "image" for RGB, else the property name."""
        return "image" if self.file_key is None else self.name

    def label(self, batch: Dict[str, Tensor], num_classes: int) -> Tensor:
        """This property's label from a batch, in its label channels (drops an RGBA image's alpha)."""
        return batch[self.label_key][..., : self.kind.label_channels(num_classes)]

    @property
    def metric_prefix(self) -> str:
        """Prefix of metric names: none for RGB (`psnr`), else the property name (`semantics_miou`)."""
        return "" if self.file_key is None else f"{self.name}_"


REGISTRY: Dict[str, PropertySpec] = {
    spec.name: spec
    for spec in (
        PropertySpec(name="rgb", short="RGB", kind=ColorKind(), file_key=None, branch="v", loss="mse", weight=1.0,
                     metric="psnr", colormap="default"),
        PropertySpec(name="semantics", short="SL", kind=ClassKind(), file_key="semantics_file_path", branch="nv",
                     loss="cross_entropy", weight=0.04, metric="miou", colormap="default", corruption="classes",
                     label_maker=SemanticsCopy()),
        PropertySpec(name="normals", short="SN", kind=NormalKind(), file_key="normals_file_path", branch="nv",
                     loss="mse", weight=1.0, metric="normal", colormap="default", corruption="dense",
                     label_maker=NormalsFromDepth()),
        PropertySpec(name="shading", short="SH", kind=ScalarKind("sigmoid"), file_key="shading_file_path", branch="v",
                     loss="l1", weight=0.1, metric="l1", colormap="gray", corruption="dense",
                     label_maker=LambertianShading()),
        PropertySpec(name="keypoints", short="KP", kind=ScalarKind("sigmoid"), file_key="keypoints_file_path",
                     branch="v", loss="l1", weight=2.0, metric="keypoint", colormap="gray", corruption="sparse",
                     label_maker=KeypointMap()),
        PropertySpec(name="edges", short="ED", kind=ScalarKind("sigmoid"), file_key="edges_file_path", branch="v",
                     loss="l1", weight=0.4, metric="edge", colormap="gray", corruption="sparse",
                     label_maker=CannyEdges()),
    )
}
"""Every property the plugin knows. RGB is always rendered; the others are optional."""

OPTIONAL_PROPERTIES: Tuple[str, ...] = tuple(name for name in REGISTRY if name != "rgb")

PropertyName = Literal[OPTIONAL_PROPERTIES]  # type: ignore[valid-type]
"""The name of an optional property, as a type: command-line options typed with it accept the registry's names only."""


def labelled_properties() -> List[PropertySpec]:
    """The properties a label maker can make, in the order they run (registry order: a maker's sources first)."""
    return [spec for spec in REGISTRY.values() if spec.label_maker is not None]


def class_property() -> PropertySpec:
    """The registry's class-valued property (semantics): what annotations and the viewer's strokes label."""
    return next(spec for spec in REGISTRY.values() if spec.kind.categorical)


def resolve_properties(
    names: Sequence[str],
    branches: Optional[Dict[str, Branch]] = None,
    weights: Optional[Dict[str, float]] = None,
    normals_mode: Literal["world", "pose"] = "world",
    losses: Optional[Dict[str, LossName]] = None,
) -> List[PropertySpec]:
    """The specs a model trains: RGB first, then `names` in registry order, with per-run overrides applied."""
    unknown = [name for name in [*names, *(branches or {}), *(weights or {}), *(losses or {})] if name not in REGISTRY]
    if unknown:
        raise ValueError(f"Unknown properties {unknown}; choose from {list(REGISTRY)}.")
    chosen = ["rgb", *(name for name in OPTIONAL_PROPERTIES if name in names)]
    specs = []
    for name in chosen:
        spec = REGISTRY[name]
        if isinstance(spec.kind, NormalKind):
            spec = replace(spec, kind=NormalKind(normals_mode))
        spec = replace(
            spec,
            branch=(branches or {}).get(name, spec.branch),
            weight=(weights or {}).get(name, spec.weight),
            loss=(losses or {}).get(name, spec.loss),
        )
        specs.append(spec)
    return specs
