"""Lambertian shading label: how much light a surface receives from a point light at the camera centre."""

from __future__ import annotations

import numpy as np


def camera_ray_directions(
    height: int, width: int, fx: float, fy: float, cx: float, cy: float, normalize: bool = True
) -> np.ndarray:
    """(H, W, 3) camera-frame ray directions through pixel centres, OpenGL axes (x right, y up, looking along -z).

    The centre of pixel (row i, column j) is at image coordinates (j + 0.5, i + 0.5), as in nerfstudio.
    With `normalize=False` the rays have z = -1, so multiplying by a z-depth map back-projects it to 3D points.
    """
    rows, cols = np.meshgrid(np.arange(height) + 0.5, np.arange(width) + 0.5, indexing="ij")
    rays = np.stack([(cols - cx) / fx, -(rows - cy) / fy, -np.ones_like(cols)], axis=-1)
    if normalize:
        rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    return rays


def shading_from_rays(normals: np.ndarray, unit_rays: np.ndarray) -> np.ndarray:
    """(H, W) shading `clip(dot(n, -v), 0, 1)` of unit normals `n` seen along unit viewing rays `v` (both (H, W, 3)).

    This is a Lambertian surface lit by a point light at the camera centre (no falloff): surfaces facing the camera
    are 1 and surfaces seen edge-on are 0. NaN normals (unknown geometry) give NaN.
    """
    return np.clip(-np.einsum("hwc,hwc->hw", normals, unit_rays), 0.0, 1.0)


def lambertian_shading(normals: np.ndarray, fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """(H, W) Lambertian shading (`shading_from_rays`) of camera-frame unit normals (H, W, 3, OpenGL axes) seen by a
    pinhole camera."""
    height, width = normals.shape[:2]
    return shading_from_rays(normals, camera_ray_directions(height, width, fx, fy, cx, cy))
