"""Label makers: how one property's label image is made from what a frame offers (image, depth, normals, class ids).
Each is the registry's `PropertySpec.label_maker`, shared by `ssnerf-label` and `ssnerf-make-scene`."""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Callable, Literal, Optional, Tuple

import cv2
import numpy as np
import tyro

from ssnerf_method.label_makers.edges import canny_edges
from ssnerf_method.label_makers.encoding import decode_normals, encode_normals, to_uint8
from ssnerf_method.label_makers.keypoints import describe_keypoint_label, keypoint_response_map
from ssnerf_method.label_makers.normals import normals_from_points, smooth_normals
from ssnerf_method.label_makers.segments import grow_in_segments
from ssnerf_method.label_makers.shading import shading_from_rays

Source = Literal["rgb", "depth", "normals", "semantics"]
"""What a frame may offer its makers (`FrameSources`' fields)."""


class Skip(Exception):
    """A maker cannot label this frame; the message is the reason a report shows."""


@dataclass
class LabelOptions:
    """The makers' settings: `ssnerf-label`'s flags, or the scene generator's fixed choices."""

    canny_low: float = 100.0
    """Canny's lower hysteresis threshold, on the 0-255 grey image's gradient magnitude."""
    canny_high: float = 200.0
    """Canny's upper hysteresis threshold: a gradient above it starts an edge."""
    normals_source: tyro.conf.Suppress[Literal["depth", "exact"]] = "depth"
    """Normal label from the depth map (the paper's), or the frame's given exact normals (a generated scene's)."""
    semantics_grow: float = 0.0
    """Grow sparse class ids (clicks) over their image segments at this graph segmentation scale (300 suits 128x96
    frames); 0: copy them as they are."""
    semantics_from: tyro.conf.Suppress[str] = "the frame's class ids"
    """Where the class ids come from, for the provenance line."""


@dataclass
class FrameSources:
    """What one frame offers the makers; a maker that lacks what it reads raises `Skip`."""

    rgb: np.ndarray
    """(H, W, 3) uint8 image."""
    rays: Callable[[float], np.ndarray]
    """Unit camera-frame viewing rays (OpenGL axes) of the frame's camera at a resolution scale: (H', W', 3)."""
    perspective: bool = True
    """Whether the camera is a pinhole camera (normals from depth need straight rays through pixel centres)."""
    depth: Optional[Callable[[], np.ndarray]] = None
    """The frame's z-depth map (any unit; it may be another resolution of the same aspect), read when asked."""
    normals_smoothing: int = 0
    """Radius (pixels) to average normals from `depth` over where the image is uniform: for rendered depth, whose
    pixel-scale bumps are not geometry; 0 for sensor depth."""
    normals: Optional[np.ndarray] = None
    """(H, W, 3) camera-frame unit normals, NaN where unknown: given with the frame, or made by a maker."""
    semantics: Optional[Callable[[], np.ndarray]] = None
    """(H, W) class ids, read when asked (`Skip` when the frame has none)."""


def with_alpha(image: np.ndarray, labelled: np.ndarray) -> np.ndarray:
    """Append an alpha channel (0 = unlabelled) when some pixels are unlabelled; else return `image` unchanged."""
    if labelled.all():
        return image
    alpha = np.where(labelled, 255, 0).astype(np.uint8)
    return np.concatenate([image.reshape(*labelled.shape, -1), alpha[..., None]], axis=-1)


class LabelMaker(ABC):
    """Makes one property's label image for a frame."""

    reads: Tuple[Source, ...] = ("rgb",)
    """The frame sources it reads (a tool enabling it alone must also run the makers that provide them)."""
    provides: Optional[Source] = None
    """A frame source it fills for the makers after it (normals, for shading)."""
    help: str = ""
    """One line for `ssnerf-label`'s switch of this property."""

    @abstractmethod
    def make(self, frame: FrameSources, options: LabelOptions) -> np.ndarray:
        """The label as written: uint8 (H, W) or (H, W, C), plus an alpha channel where some pixels are unlabelled."""

    @abstractmethod
    def describe(self, options: LabelOptions) -> str:
        """How the label was made, for the dataset's provenance record."""

    def use_label(self, frame: FrameSources, label: np.ndarray) -> None:
        """Take a label the frame already has (as its kind reads it) as this maker's source for later makers."""


class SemanticsCopy(LabelMaker):
    """Class ids are never derived: they are copied from the frame's source (annotations, a ray caster)."""

    reads = ("semantics",)
    help = "Semantic labels, from --annotations or --semantics-dir (never derived)."

    def make(self, frame: FrameSources, options: LabelOptions) -> np.ndarray:
        if frame.semantics is None:
            raise Skip("not given (semantics are never derived; pass --annotations)")
        class_ids = frame.semantics().astype(np.uint8)
        if options.semantics_grow > 0:
            class_ids = grow_in_segments(class_ids, frame.rgb, options.semantics_grow)
        return class_ids

    def describe(self, options: LabelOptions) -> str:
        grown = (f", grown over the image's segments (graph segmentation, scale {options.semantics_grow:g})"
                 if options.semantics_grow > 0 else "")
        return f"copied from {options.semantics_from}{grown}"


class NormalsFromDepth(LabelMaker):
    """Camera-frame unit normals by finite differences of back-projected depth (the paper's SN) as (n + 1) / 2,
    alpha 0 where none; or the frame's given normals (`normals_source == "exact"`)."""

    reads = ("depth",)
    provides = "normals"
    help = "Surface normals from each frame's depth map (frames without one: rendered by --depth-from, or skipped)."

    def make(self, frame: FrameSources, options: LabelOptions) -> np.ndarray:
        if options.normals_source == "exact":
            if frame.normals is None:
                raise Skip("no exact normals given")
            return to_uint8(encode_normals(frame.normals))
        if frame.depth is None:
            raise Skip("no depth_file_path (ssnerf-label's depth model renders it unless --depth-model-steps 0)")
        if not frame.perspective:
            raise Skip("camera model is not a perspective (pinhole) camera")
        depth = frame.depth()
        height, width = frame.rgb.shape[:2]
        rays = frame.rays(depth.shape[1] / width)
        valid = np.isfinite(depth) & (depth > 0)
        points = np.where(valid, depth, 0.0)[..., None] * rays / np.maximum(-rays[..., 2:], 1e-9)
        normals = normals_from_points(points, valid & (rays[..., 2] < 0))
        if depth.shape != (height, width):  # derived at the depth's resolution, then mapped to image pixels
            normals = cv2.resize(normals, (width, height), interpolation=cv2.INTER_NEAREST)
        if frame.normals_smoothing > 0:
            normals = smooth_normals(normals, frame.rgb, frame.normals_smoothing)
        if frame.normals is None:
            frame.normals = normals
        return with_alpha(to_uint8(encode_normals(normals)), np.isfinite(normals).all(axis=-1))

    def describe(self, options: LabelOptions) -> str:
        if options.normals_source == "exact":
            return "the ray caster's exact normals, camera frame, OpenGL axes, (n + 1) / 2 * 255"
        return ("from depth by finite differences: camera frame, OpenGL axes (x right, y up, z towards the viewer), "
                "(n + 1) / 2 * 255; alpha 0 where depth is invalid or discontinuous")

    def use_label(self, frame: FrameSources, label: np.ndarray) -> None:
        normals = decode_normals(label.astype(np.float64))
        frame.normals = normals / np.linalg.norm(normals, axis=-1, keepdims=True)


class LambertianShading(LabelMaker):
    """Shading of a Lambertian surface lit by a point light at the camera centre, from the frame's normals."""

    reads = ("normals",)
    help = "Lambertian shading from the frame's normals (given or derived)."

    def make(self, frame: FrameSources, options: LabelOptions) -> np.ndarray:
        if frame.normals is None:
            raise Skip("no normals (given or derived from depth)")
        shading = shading_from_rays(frame.normals, frame.rays(1.0))
        return with_alpha(to_uint8(shading), np.isfinite(shading))

    def describe(self, options: LabelOptions) -> str:
        return "Lambertian, point light at the camera centre: clip(dot(n, -view_dir), 0, 1)"


class KeypointMap(LabelMaker):
    """A keypoint map of the image (`labels/keypoints.py`)."""

    help = "Keypoint map of the RGB image (SURF's blob response)."

    def make(self, frame: FrameSources, options: LabelOptions) -> np.ndarray:
        return to_uint8(keypoint_response_map(frame.rgb))

    def describe(self, options: LabelOptions) -> str:
        return describe_keypoint_label()


class CannyEdges(LabelMaker):
    """Canny edges of the 8-bit grey image."""

    help = "Canny edges of the RGB image."

    def make(self, frame: FrameSources, options: LabelOptions) -> np.ndarray:
        return to_uint8(canny_edges(frame.rgb, options.canny_low, options.canny_high))

    def describe(self, options: LabelOptions) -> str:
        return f"Canny, thresholds {options.canny_low:g} / {options.canny_high:g} on the 8-bit grey image"
