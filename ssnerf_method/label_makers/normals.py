"""Surface-normal label from a z-depth map: camera-frame unit normals by finite differences of back-projected points."""

from __future__ import annotations

import cv2
import numpy as np

from ssnerf_method.label_makers.shading import camera_ray_directions


def backproject_depth(depth: np.ndarray, fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """(H, W, 3) camera-frame points (OpenGL axes, camera looks along -z) of a z-depth map (H, W)."""
    height, width = depth.shape
    return depth[..., None] * camera_ray_directions(height, width, fx, fy, cx, cy, normalize=False)


def _pixel_derivative(points: np.ndarray, usable: np.ndarray, axis: int) -> np.ndarray:
    """Derivative of `points` along image `axis` (0 rows, 1 columns); NaN where no usable neighbour difference.

    `usable` marks the forward differences (shape reduced by one along `axis`) that do not cross a discontinuity.
    Central differences are used where both sides are usable, else the usable one-sided difference.
    """
    forward = np.diff(points, axis=axis)
    forward[~usable] = np.nan
    pad_before = [(0, 0)] * 3
    pad_after = [(0, 0)] * 3
    pad_before[axis] = (1, 0)
    pad_after[axis] = (0, 1)
    backward_at = np.pad(forward, pad_before, constant_values=np.nan)  # difference to the previous pixel
    forward_at = np.pad(forward, pad_after, constant_values=np.nan)  # difference to the next pixel
    central = 0.5 * (backward_at + forward_at)
    return np.where(np.isnan(central), np.where(np.isnan(forward_at), backward_at, forward_at), central)


def normals_from_points(points: np.ndarray, valid: np.ndarray, min_angle_deg: float = 5.0) -> np.ndarray:
    """(H, W, 3) unit normals, facing the camera, of an (H, W, 3) grid of camera-frame points (camera at the origin).

    This is the paper's SN = (-dz/dx, -dz/dy, 1), normalised, for the surface z(x, y) through the back-projected
    points, computed for any camera model: the normal is the cross product of the points' derivatives along image
    rows and columns (which is parallel to (-dz/dx, -dz/dy, 1) by the chain rule), oriented towards the camera.
    A difference between neighbouring pixels counts as a depth discontinuity, and is not used, when the 3D segment
    joining them lies within `min_angle_deg` of the viewing ray (the surface would be seen exactly edge-on);
    genuinely tilted surfaces such as a far floor are kept. Pixels not `valid`, or with no usable difference along
    rows or columns, are NaN.
    """
    points = np.where(valid[..., None], points, 0.0)
    view = points / np.maximum(np.linalg.norm(points, axis=-1, keepdims=True), 1e-12)
    cos_limit = np.cos(np.deg2rad(min_angle_deg))

    derivatives = []
    for axis in (0, 1):
        segment = np.diff(points, axis=axis)
        length = np.maximum(np.linalg.norm(segment, axis=-1), 1e-12)
        start_view = view[:-1] if axis == 0 else view[:, :-1]
        cosine = np.abs(np.einsum("hwc,hwc->hw", segment, start_view)) / length
        both_valid = (valid[:-1] & valid[1:]) if axis == 0 else (valid[:, :-1] & valid[:, 1:])
        derivatives.append(_pixel_derivative(points, both_valid & (cosine < cos_limit), axis))

    d_rows, d_cols = derivatives
    normals = np.cross(d_cols, d_rows)
    normals *= np.where(np.einsum("hwc,hwc->hw", normals, points) > 0, -1.0, 1.0)[..., None]
    norm = np.linalg.norm(normals, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        normals = normals / norm
    normals[~valid | ~np.isfinite(norm[..., 0]) | (norm[..., 0] <= 0)] = np.nan
    return normals


GUIDED_EPS = 0.01
"""Guided filter's regulariser for `smooth_normals`, with the guide image in [0, 1]: colour differences well above
its square root (0.1) keep normals apart; smaller ones (texture on one surface) are averaged over."""


def smooth_normals(
    normals: np.ndarray, guide: np.ndarray, radius: int, eps: float = GUIDED_EPS
) -> np.ndarray:
    """`normals` (H, W, 3; NaN where unknown) averaged over `radius` pixels where the image `guide` (H, W, 3 uint8) is
    uniform, by OpenCV's guided filter (He et al.): the edges of the image stay the edges of the normals.

    For normals from a radiance field's depth, whose pixel-scale bumps follow the texture and are not geometry. NaN
    pixels take no part and stay NaN; the result is renormalised.
    """
    unknown = ~np.isfinite(normals).all(axis=-1)
    image = guide.astype(np.float32) / 255.0
    weight = (~unknown).astype(np.float32)
    known_normals = np.where(unknown[..., None], 0.0, normals).astype(np.float32)
    summed = cv2.ximgproc.guidedFilter(image, known_normals, radius, eps)
    total = cv2.ximgproc.guidedFilter(image, weight, radius, eps)
    smoothed = summed.astype(np.float64) / np.maximum(total.astype(np.float64), 1e-3)[..., None]
    with np.errstate(invalid="ignore", divide="ignore"):
        smoothed /= np.linalg.norm(smoothed, axis=-1, keepdims=True)
    smoothed[unknown | ~np.isfinite(smoothed).all(axis=-1)] = np.nan
    return smoothed


def normals_from_depth(
    depth: np.ndarray, fx: float, fy: float, cx: float, cy: float, min_angle_deg: float = 5.0
) -> np.ndarray:
    """(H, W, 3) camera-frame unit normals (OpenGL axes: x right, y up, z towards the viewer) of a pinhole z-depth map.

    See `normals_from_points`; pixels with depth <= 0 (or non-finite) are NaN.
    """
    valid = np.isfinite(depth) & (depth > 0)
    points = backproject_depth(np.where(valid, depth, 0.0), fx, fy, cx, cy)
    return normals_from_points(points, valid, min_angle_deg)
