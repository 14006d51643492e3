"""Textures of the default scene's room: colour as a function of the hit point, with features of a few centimetres
or more (plank seams, tiles, book spines, painting cells, window bars, fabric checks), so edge and keypoint detectors
fire while a small NeRF can still fit the images."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Tuple

import numpy as np

RGB = Tuple[float, float, float]


# --------------------------------------------------------------------------------------------------------------------
# Texture helpers: all take points local to the primitive's bounding-box minimum corner.


def _face_uv(q: np.ndarray, n: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """In-plane coordinates on each point's face: (horizontal, height) on walls, (x, z) on horizontal faces."""
    axis = np.abs(n).argmax(axis=1)
    u = np.where(axis == 0, q[:, 2], q[:, 0])
    v = np.where(axis == 1, q[:, 2], q[:, 1])
    return u, v


def _face_size(n: np.ndarray, extent: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """Size of each point's face along `_face_uv`'s u and v."""
    axis = np.abs(n).argmax(axis=1)
    su = np.where(axis == 0, extent[2], extent[0])
    sv = np.where(axis == 1, extent[2], extent[1])
    return su, sv


def _on_front(n: np.ndarray, front: Tuple[int, int]) -> np.ndarray:
    """Whether each point lies on the face whose outward normal is `sign * e_axis` for `front = (axis, sign)`."""
    axis, sign = front
    return n[:, axis] * sign > 0.5


def _front_face(
    q: np.ndarray, n: np.ndarray, extent: np.ndarray, front: Tuple[int, int]
) -> Tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Mask of the points on the `front` face, their in-plane coordinates (u, v) and the face's size (su, sv)."""
    mask = _on_front(n, front)
    u, v = _face_uv(q[mask], n[mask])
    su, sv = _face_size(n[mask], extent)
    return mask, u, v, su, sv


def _hash(a: np.ndarray, b: Optional[np.ndarray] = None) -> np.ndarray:
    """Deterministic pseudo-random value in [0, 1) per integer cell (for per-plank / per-tile variation)."""
    a = a.astype(np.int64)
    b = np.zeros_like(a) if b is None else b.astype(np.int64)
    h = ((a * 73856093) ^ (b * 19349663)) % 1000003
    return ((h * 7919 + 104729) % 1000003) / 1000003.0


def _fill(n: int, color: RGB) -> np.ndarray:
    return np.tile(np.asarray(color, dtype=np.float64), (n, 1))


def _rect_border(u: np.ndarray, v: np.ndarray, su: np.ndarray, sv: np.ndarray) -> np.ndarray:
    """Distance of each point to the nearest edge of its face."""
    return np.minimum(np.minimum(u, su - u), np.minimum(v, sv - v))


@dataclass(frozen=True)
class Solid:
    """Uniform colour."""

    color: RGB

    def __call__(self, q: np.ndarray, n: np.ndarray, extent: np.ndarray) -> np.ndarray:
        return _fill(len(q), self.color)


@dataclass(frozen=True)
class WoodGrain:
    """Wood: a soft, wavy sinusoidal grain (period ~25 cm) along one local axis."""

    color: RGB
    axis: int = 0
    period: float = 0.25

    def __call__(self, q: np.ndarray, n: np.ndarray, extent: np.ndarray) -> np.ndarray:
        other = q[:, (self.axis + 1) % 3] + q[:, (self.axis + 2) % 3]
        phase = q[:, self.axis] / self.period + 0.6 * np.sin(2 * np.pi * other / 0.7)
        return _fill(len(q), self.color) * (1.0 + 0.08 * np.sin(2 * np.pi * phase))[:, None]


@dataclass(frozen=True)
class Planks:
    """Wooden floor: planks along x with staggered ends, per-plank tone and dark 2 cm seams."""

    color: RGB
    seam: RGB
    width: float = 0.2
    length: float = 1.2
    seam_width: float = 0.02

    def __call__(self, q: np.ndarray, n: np.ndarray, extent: np.ndarray) -> np.ndarray:
        row = np.floor(q[:, 2] / self.width)
        along = q[:, 0] + _hash(row) * self.length
        column = np.floor(along / self.length)
        tone = 0.8 + 0.35 * _hash(row, column) + 0.05 * np.sin(2 * np.pi * along / 0.37 + row)
        albedo = _fill(len(q), self.color) * tone[:, None]
        seam = (np.mod(q[:, 2], self.width) < self.seam_width) | (np.mod(along, self.length) < self.seam_width)
        albedo[seam] = self.seam
        return albedo


@dataclass(frozen=True)
class Tiles:
    """Square tiles with grout lines on each face (ceiling)."""

    color: RGB
    line: RGB
    size: float = 0.6
    line_width: float = 0.025

    def __call__(self, q: np.ndarray, n: np.ndarray, extent: np.ndarray) -> np.ndarray:
        u, v = _face_uv(q, n)
        albedo = _fill(len(q), self.color)
        albedo[(np.mod(u, self.size) < self.line_width) | (np.mod(v, self.size) < self.line_width)] = self.line
        return albedo


@dataclass(frozen=True)
class WallPaint:
    """Wall: painted (optionally wallpaper-striped) above a darker wainscot with a rail and a light skirting."""

    upper: RGB
    lower: RGB
    rail: RGB
    stripe: Optional[RGB] = None
    stripe_period: float = 0.4
    rail_height: float = 0.9
    rail_width: float = 0.05
    skirting_height: float = 0.1

    def __call__(self, q: np.ndarray, n: np.ndarray, extent: np.ndarray) -> np.ndarray:
        u, v = _face_uv(q, n)
        albedo = _fill(len(q), self.upper)
        if self.stripe is not None:
            albedo[np.mod(u, self.stripe_period) < self.stripe_period / 2] = self.stripe
        albedo[v < self.rail_height + self.rail_width] = self.rail
        albedo[v < self.rail_height] = self.lower
        albedo[v < self.skirting_height] = self.rail
        return albedo


@dataclass(frozen=True)
class Checker:
    """Two-colour checkerboard on each face (fabric, quilting)."""

    color_a: RGB
    color_b: RGB
    size: float = 0.15

    def __call__(self, q: np.ndarray, n: np.ndarray, extent: np.ndarray) -> np.ndarray:
        u, v = _face_uv(q, n)
        odd = (np.floor(u / self.size) + np.floor(v / self.size)) % 2 == 1
        albedo = _fill(len(q), self.color_a)
        albedo[odd] = self.color_b
        return albedo


@dataclass(frozen=True)
class Stripes:
    """Bands cycling through `colors` along one local axis (duvet, vases, boxes, foliage)."""

    colors: Tuple[RGB, ...]
    period: float
    axis: int

    def __call__(self, q: np.ndarray, n: np.ndarray, extent: np.ndarray) -> np.ndarray:
        index = np.floor(q[:, self.axis] / self.period).astype(np.int64) % len(self.colors)
        return np.asarray(self.colors, dtype=np.float64)[index]


@dataclass(frozen=True)
class Rug:
    """Rug (top face): border band, a thin accent line, and a field of diamonds."""

    border: RGB
    field: RGB
    accent: RGB
    border_width: float = 0.12
    diamond: float = 0.3

    def __call__(self, q: np.ndarray, n: np.ndarray, extent: np.ndarray) -> np.ndarray:
        u, v = _face_uv(q, n)
        edge = _rect_border(u, v, *_face_size(n, extent))
        diamonds = (np.floor((u + v) / self.diamond) + np.floor((u - v) / self.diamond)) % 2 == 1
        albedo = _fill(len(q), self.field)
        albedo[diamonds] = self.accent
        albedo[edge < self.border_width + 0.04] = self.accent
        albedo[edge < self.border_width] = self.border
        return albedo


@dataclass(frozen=True)
class Cabinet:
    """Furniture front with `cols` x `rows` doors/drawers (dark gaps) and a handle near each panel's top."""

    color: RGB
    front: Tuple[int, int]
    cols: int = 2
    rows: int = 1
    gap: RGB = (0.12, 0.09, 0.07)
    handle: Optional[RGB] = (0.75, 0.75, 0.72)
    gap_width: float = 0.015

    def __call__(self, q: np.ndarray, n: np.ndarray, extent: np.ndarray) -> np.ndarray:
        albedo = WoodGrain(self.color, axis=1)(q, n, extent)
        front, u, v, su, sv = _front_face(q, n, extent, self.front)
        pu, pv = su / self.cols, sv / self.rows
        iu, iv = np.mod(u, pu), np.mod(v, pv)
        face = albedo[front]
        if self.handle is not None:
            handle = (np.abs(iu - pu / 2) < 0.06) & (np.abs(iv - (pv - 0.08)) < 0.015)
            face[handle] = self.handle
        gap = (iu < self.gap_width) | (iv < self.gap_width) | (_rect_border(u, v, su, sv) < 2 * self.gap_width)
        face[gap] = self.gap
        albedo[front] = face
        return albedo


@dataclass(frozen=True)
class Books:
    """A row of books (front = spines, other faces = pages): book `i` spans `edges[i]..edges[i+1]` along x."""

    edges: Tuple[float, ...]
    colors: Tuple[RGB, ...]
    front: Tuple[int, int] = (2, 1)
    pages: RGB = (0.9, 0.87, 0.78)
    gap: RGB = (0.1, 0.08, 0.06)

    def __call__(self, q: np.ndarray, n: np.ndarray, extent: np.ndarray) -> np.ndarray:
        book = np.clip(np.searchsorted(np.asarray(self.edges), q[:, 0], side="right") - 1, 0, len(self.colors) - 1)
        spine = np.asarray(self.colors)[book]
        height = q[:, 1] / extent[1]
        label = (height > 0.6) & (height < 0.72)
        spine[label] = 0.45 * spine[label] + 0.55 * np.array([0.95, 0.85, 0.45])
        albedo = np.where(_on_front(n, self.front)[:, None], spine, np.asarray(self.pages))
        edges = np.asarray(self.edges)
        nearest = np.abs(q[:, 0][:, None] - edges[None, :]).min(axis=1)
        albedo[nearest < 0.006] = self.gap
        return albedo


@dataclass(frozen=True)
class Mondrian:
    """Painting in the style of Mondrian: a gold frame around a 3x3 grid of colour cells with black bars."""

    cells: Tuple[RGB, ...]
    front: Tuple[int, int]
    splits_u: Tuple[float, float] = (0.3, 0.72)
    splits_v: Tuple[float, float] = (0.38, 0.75)
    frame: RGB = (0.7, 0.55, 0.25)
    frame_width: float = 0.05
    bar_width: float = 0.025

    def __call__(self, q: np.ndarray, n: np.ndarray, extent: np.ndarray) -> np.ndarray:
        albedo = _fill(len(q), self.frame)
        front, u, v, su, sv = _front_face(q, n, extent, self.front)
        s, t = u / su, v / sv
        col = np.searchsorted(np.asarray(self.splits_u), s)
        row = np.searchsorted(np.asarray(self.splits_v), t)
        face = np.asarray(self.cells)[row * 3 + col]
        bar_u = np.abs(s[:, None] - np.asarray(self.splits_u)).min(axis=1) * su < self.bar_width / 2
        bar_v = np.abs(t[:, None] - np.asarray(self.splits_v)).min(axis=1) * sv < self.bar_width / 2
        face[bar_u | bar_v] = (0.05, 0.05, 0.05)
        inside = _rect_border(u, v, su, sv) >= self.frame_width
        albedo[front] = np.where(inside[:, None], face, albedo[front])
        return albedo


@dataclass(frozen=True)
class Landscape:
    """Painting of a landscape: sky, a sun disc, a zig-zag mountain range and a lake, in a dark frame."""

    sky: RGB
    sun: RGB
    mountain: RGB
    lake: RGB
    front: Tuple[int, int]
    frame: RGB = (0.25, 0.15, 0.08)
    frame_width: float = 0.05

    def __call__(self, q: np.ndarray, n: np.ndarray, extent: np.ndarray) -> np.ndarray:
        albedo = _fill(len(q), self.frame)
        front, u, v, su, sv = _front_face(q, n, extent, self.front)
        s, t = u / su, v / sv
        face = _fill(len(s), self.sky) * (0.8 + 0.25 * t)[:, None]
        face[(s - 0.72) ** 2 * (su / sv) ** 2 + (t - 0.72) ** 2 < 0.13**2] = self.sun
        ridge = 0.3 + 0.3 * np.abs(np.mod(s * 3.0, 1.0) - 0.5) * 2 * (1 - 0.3 * s)
        face[t < ridge] = self.mountain
        face[t < 0.22] = self.lake
        inside = _rect_border(u, v, su, sv) >= self.frame_width
        albedo[front] = np.where(inside[:, None], face, albedo[front])
        return albedo


@dataclass(frozen=True)
class Television:
    """TV: dark bezel, near-black screen with a soft diagonal reflection band, a small light logo."""

    front: Tuple[int, int]
    body: RGB = (0.1, 0.1, 0.11)
    screen: RGB = (0.02, 0.025, 0.04)
    bezel_width: float = 0.035

    def __call__(self, q: np.ndarray, n: np.ndarray, extent: np.ndarray) -> np.ndarray:
        albedo = _fill(len(q), self.body)
        front, u, v, su, sv = _front_face(q, n, extent, self.front)
        s, t = u / su, v / sv
        face = _fill(len(s), self.screen)
        glare = 0.6 * s + 0.4 * t
        face[(glare > 0.55) & (glare < 0.68)] = (0.1, 0.11, 0.14)
        face[_rect_border(u, v, su, sv) < self.bezel_width] = self.body
        face[(np.abs(u - su / 2) < 0.04) & (v < self.bezel_width * 0.7) & (v > self.bezel_width * 0.3)] = 0.7
        albedo[front] = face
        return albedo


@dataclass(frozen=True)
class WindowView:
    """Window (emissive): frame and cross bars around a bright sky over green hills."""

    front: Tuple[int, int]
    frame: RGB = (0.42, 0.36, 0.3)
    frame_width: float = 0.06
    bar_width: float = 0.04

    def __call__(self, q: np.ndarray, n: np.ndarray, extent: np.ndarray) -> np.ndarray:
        albedo = _fill(len(q), self.frame)
        front, u, v, su, sv = _front_face(q, n, extent, self.front)
        s, t = u / su, v / sv
        top, horizon = np.array([0.55, 0.72, 0.98]), np.array([0.88, 0.93, 1.0])
        face = horizon + (top - horizon) * t[:, None]
        hills = t < 0.3 + 0.08 * np.sin(2 * np.pi * 1.3 * s + 0.5)
        face[hills] = (0.35, 0.6, 0.3)
        face[hills & (t < 0.15 + 0.05 * np.sin(2 * np.pi * 2.1 * s))] = (0.25, 0.45, 0.22)
        bars = (np.abs(u - su / 2) < self.bar_width / 2) | (np.abs(t - 0.62) * sv < self.bar_width / 2)
        face[bars | (_rect_border(u, v, su, sv) < self.frame_width)] = self.frame
        albedo[front] = face
        return albedo


@dataclass(frozen=True)
class BeachBall:
    """Sphere split into six coloured meridian segments with a white cap."""

    colors: Tuple[RGB, ...]

    def __call__(self, q: np.ndarray, n: np.ndarray, extent: np.ndarray) -> np.ndarray:
        segment = np.floor((np.arctan2(n[:, 2], n[:, 0]) + np.pi) / (2 * np.pi) * len(self.colors)).astype(np.int64)
        albedo = np.asarray(self.colors, dtype=np.float64)[segment % len(self.colors)]
        albedo[n[:, 1] > 0.85] = 0.95
        return albedo


# --------------------------------------------------------------------------------------------------------------------
# Lighting and the room itself.


GRAIN_CELLS_M = (0.006, 0.015, 0.04)
"""Cell sizes (metres) of the grain's octaves: texture at the scale of a photo's pixels, which SIFT matches."""


def _value_noise(points: np.ndarray, cell: float, octave: int) -> np.ndarray:
    """Smoothly interpolated hashed values in [0, 1) on a 3D lattice of `cell` metres (one octave of value noise)."""
    scaled = points / cell
    base = np.floor(scaled).astype(np.int64)
    frac = scaled - base
    weight = frac * frac * (3.0 - 2.0 * frac)  # smoothstep: no creases at the lattice faces
    value = np.zeros(len(points))
    for corner in np.ndindex(2, 2, 2):
        lattice = base + np.asarray(corner)
        cell_value = _hash(lattice[:, 0] * 92821 + lattice[:, 1] + 7 * octave, lattice[:, 2])
        w = np.prod(np.where(np.asarray(corner) == 1, weight, 1.0 - weight), axis=1)
        value += w * cell_value
    return value


def surface_grain(points: np.ndarray, amount: float) -> np.ndarray:
    """(N,) albedo multipliers in [1 - amount, 1 + amount]: fixed fine texture in world space (wood pores, plaster,
    fabric weave), so photos of the room carry the detail a structure-from-motion matcher needs."""
    noise = sum(_value_noise(points, cell, octave) for octave, cell in enumerate(GRAIN_CELLS_M)) / len(GRAIN_CELLS_M)
    return 1.0 + amount * (2.0 * noise - 1.0) * 1.7  # the mean of three octaves spans about 0.2-0.8
