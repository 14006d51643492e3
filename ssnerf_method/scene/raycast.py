"""Vectorised numpy ray caster for the procedural room: boxes, vertical cylinders and spheres.

Rays share one origin and are cast one numpy pass per primitive, directions as contiguous (3, N) rows. Camera rays
have camera-frame z = -1 (OpenGL: x right, y up, looking along -z), so a hit's ray parameter `t` is its z-depth.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence, Tuple, Union

import numpy as np

Vec3 = Tuple[float, float, float]

Texture = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]
"""Albedo of hit points: `(local_points (N,3), world_normals (N,3), extent (3,)) -> rgb (N,3) in [0,1]`; points are
relative to the bounding box's minimum corner, so a pattern moves with its object."""

_EPS = 1e-6


@dataclass(frozen=True)
class Box:
    """Axis-aligned box between corners `lo` and `hi` (world metres)."""

    lo: Vec3
    hi: Vec3

    @property
    def bounds(self) -> Tuple[np.ndarray, np.ndarray]:
        return np.asarray(self.lo, dtype=np.float64), np.asarray(self.hi, dtype=np.float64)

    def intersect(self, origin: np.ndarray, directions: np.ndarray, inverse: np.ndarray) -> np.ndarray:
        """Slab test: ray parameter of the entry hit, `inf` where the ray misses (the origin is outside)."""
        lo, hi = self.bounds
        t_near, t_far = np.zeros(directions.shape[1]), np.full(directions.shape[1], np.inf)
        for axis in range(3):
            t0 = (lo[axis] - origin[axis]) * inverse[axis]
            t1 = (hi[axis] - origin[axis]) * inverse[axis]
            np.maximum(t_near, np.minimum(t0, t1), out=t_near)
            np.minimum(t_far, np.maximum(t0, t1), out=t_far)
        return np.where((t_near <= t_far) & (t_near > _EPS), t_near, np.inf)

    def normal(self, points: np.ndarray) -> np.ndarray:
        """Outward normal of the face each surface point lies on."""
        lo, hi = self.bounds
        dist = np.concatenate([np.abs(points - lo), np.abs(points - hi)], axis=1)
        face = dist.argmin(axis=1)
        normals = np.zeros_like(points)
        normals[np.arange(len(points)), face % 3] = np.where(face < 3, -1.0, 1.0)
        return normals


@dataclass(frozen=True)
class Cylinder:
    """Vertical (world y axis) capped cylinder around `(x, z)` from height `y0` to `y1`."""

    x: float
    z: float
    radius: float
    y0: float
    y1: float

    @property
    def bounds(self) -> Tuple[np.ndarray, np.ndarray]:
        r = self.radius
        return np.array([self.x - r, self.y0, self.z - r]), np.array([self.x + r, self.y1, self.z + r])

    def intersect(self, origin: np.ndarray, directions: np.ndarray, inverse: np.ndarray) -> np.ndarray:
        """Nearest hit of the side or the two caps, `inf` on a miss."""
        ox, oy, oz = origin[0] - self.x, origin[1], origin[2] - self.z
        dx, dy, dz = directions
        a = dx * dx + dz * dz
        b = 2.0 * (ox * dx + oz * dz)
        c = ox * ox + oz * oz - self.radius**2
        disc = b * b - 4.0 * a * c
        with np.errstate(invalid="ignore"):
            t_side = (-b - np.sqrt(disc)) / (2.0 * a)
        y_side = oy + t_side * dy
        t_side = np.where((disc >= 0) & (t_side > _EPS) & (y_side >= self.y0) & (y_side <= self.y1), t_side, np.inf)
        best = t_side
        for y_cap in (self.y0, self.y1):
            t_cap = (y_cap - oy) * inverse[1]
            rx, rz = ox + t_cap * dx, oz + t_cap * dz
            inside = (t_cap > _EPS) & (rx * rx + rz * rz <= self.radius**2)
            best = np.minimum(best, np.where(inside, t_cap, np.inf))
        return best

    def normal(self, points: np.ndarray) -> np.ndarray:
        """Radial normal on the side, +-y on the caps (whichever surface the point is closest to)."""
        radial = points[:, [0, 2]] - np.array([self.x, self.z])
        r = np.linalg.norm(radial, axis=1)
        cap_dist = np.minimum(np.abs(points[:, 1] - self.y0), np.abs(points[:, 1] - self.y1))
        on_cap = cap_dist < np.abs(r - self.radius)
        normals = np.zeros_like(points)
        normals[:, 0] = radial[:, 0] / np.maximum(r, _EPS)
        normals[:, 2] = radial[:, 1] / np.maximum(r, _EPS)
        cap_sign = np.where(np.abs(points[:, 1] - self.y1) < np.abs(points[:, 1] - self.y0), 1.0, -1.0)
        normals[on_cap] = 0.0
        normals[on_cap, 1] = cap_sign[on_cap]
        return normals


@dataclass(frozen=True)
class Sphere:
    """Sphere of `radius` around `center`."""

    center: Vec3
    radius: float

    @property
    def bounds(self) -> Tuple[np.ndarray, np.ndarray]:
        c = np.asarray(self.center, dtype=np.float64)
        return c - self.radius, c + self.radius

    def intersect(self, origin: np.ndarray, directions: np.ndarray, inverse: np.ndarray) -> np.ndarray:
        """Nearest front hit, `inf` on a miss."""
        oc = origin - np.asarray(self.center)
        a = np.einsum("ij,ij->j", directions, directions)
        b = 2.0 * (oc @ directions)
        c = oc @ oc - self.radius**2
        disc = b * b - 4.0 * a * c
        with np.errstate(invalid="ignore"):
            t = (-b - np.sqrt(disc)) / (2.0 * a)
        return np.where((disc >= 0) & (t > _EPS), t, np.inf)

    def normal(self, points: np.ndarray) -> np.ndarray:
        return (points - np.asarray(self.center)) / self.radius


Shape = Union[Box, Cylinder, Sphere]


@dataclass(frozen=True)
class Primitive:
    """One textured, labelled object of the scene."""

    name: str
    shape: Shape
    semantic_id: int
    texture: Texture
    emissive: bool = False
    """Emissive surfaces (window view, lamps) show their albedo as radiance, unaffected by the lights."""


@dataclass
class RayHits:
    """First hit of each ray; missed rays have `t = inf`, semantic 0 (void) and zero normal/albedo."""

    t: np.ndarray
    """(N,) ray parameter; the z-depth for camera rays built by `PinholeCamera.rays`."""
    position: np.ndarray
    """(N, 3) world hit points."""
    normal: np.ndarray
    """(N, 3) world unit normals."""
    semantic: np.ndarray
    """(N,) semantic class ids (uint8)."""
    albedo: np.ndarray
    """(N, 3) albedo in [0, 1]."""
    emissive: np.ndarray
    """(N,) whether the hit surface is emissive."""


def cast_rays(primitives: Sequence[Primitive], origin: np.ndarray, directions: np.ndarray) -> RayHits:
    """The nearest hit of each ray (common `origin` (3,), `directions` (N, 3)); a shape's `intersect` gets (3, N)
    directions and reciprocals and returns each ray's first hit parameter in front of the origin, or `inf`."""
    origin = np.asarray(origin, dtype=np.float64)
    rows = np.ascontiguousarray(np.where(np.abs(directions) < 1e-12, 1e-12, directions).T)  # finite reciprocals
    inverse = 1.0 / rows
    n = len(directions)
    t = np.full(n, np.inf)
    owner = np.full(n, -1)
    for index, primitive in enumerate(primitives):
        t_prim = primitive.shape.intersect(origin, rows, inverse)
        closer = t_prim < t
        np.copyto(t, t_prim, where=closer)
        np.copyto(owner, index, where=closer)

    hit = np.isfinite(t)
    position = origin + np.where(hit, t, 0.0)[:, None] * directions
    normal = np.zeros((n, 3))
    semantic = np.zeros(n, dtype=np.uint8)
    albedo = np.zeros((n, 3))
    emissive = np.zeros(n, dtype=bool)
    for index, primitive in enumerate(primitives):
        sel = np.flatnonzero(owner == index)
        if sel.size == 0:
            continue
        lo, hi = primitive.shape.bounds
        normal[sel] = primitive.shape.normal(position[sel])
        albedo[sel] = primitive.texture(position[sel] - lo, normal[sel], hi - lo)
        semantic[sel] = primitive.semantic_id
        emissive[sel] = primitive.emissive
    return RayHits(t=t, position=position, normal=normal, semantic=semantic, albedo=albedo, emissive=emissive)


@dataclass(frozen=True)
class PinholeCamera:
    """Pinhole camera with a camera-to-world pose in nerfstudio's OpenGL convention (x right, y up, looks -z)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    camera_to_world: np.ndarray
    """(4, 4) camera-to-world matrix."""

    def rays(self, pixel_x: np.ndarray, pixel_y: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        """Camera centre (3,) and world ray directions (N, 3) through continuous pixel coordinates (column j's centre
        at x = j + 0.5); directions have camera-frame z = -1, so a hit's `t` is its z-depth."""
        cam = np.stack(
            [(pixel_x - self.cx) / self.fx, -(pixel_y - self.cy) / self.fy, -np.ones_like(pixel_x)], axis=-1
        ).reshape(-1, 3)
        rotation = self.camera_to_world[:3, :3]
        return self.camera_to_world[:3, 3].copy(), cam @ rotation.T


def pixel_grid(width: int, height: int, samples_per_side: int = 1) -> Tuple[np.ndarray, np.ndarray]:
    """Coordinates (height, width, s**2) of the centres of an s x s subdivision of each pixel (s: samples_per_side)."""
    offsets = (np.arange(samples_per_side) + 0.5) / samples_per_side
    sub_y, sub_x = np.meshgrid(offsets, offsets, indexing="ij")
    rows, cols = np.meshgrid(np.arange(height), np.arange(width), indexing="ij")
    pixel_x = cols[..., None] + sub_x.reshape(-1)
    pixel_y = rows[..., None] + sub_y.reshape(-1)
    return pixel_x.astype(np.float64), pixel_y.astype(np.float64)
