"""The procedural furnished room of the default SS-NeRF scene: labelled, textured primitives and their lighting.

The room spans x in [-3, 3] m, y (up) in [0, 3] m and z in [-2.5, 2.5] m. It holds a bed, a bookshelf with books,
a sofa, a TV on a stand, a table with chairs, a wardrobe, two paintings, a window and small objects, labelled with
the NYUv2-13 classes, each with a texture of `textures.py`. The furniture layout is fixed; the seed varies colours,
book widths and the painting's cell colours.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import List, Sequence, Tuple

import numpy as np

from ssnerf_method.data.classes import CLASS_ID
from ssnerf_method.scene.raycast import Box, Cylinder, Primitive, RayHits, Shape, Sphere, Texture
from ssnerf_method.scene.textures import (
    RGB,
    BeachBall,
    Books,
    Cabinet,
    Checker,
    Landscape,
    Mondrian,
    Planks,
    Rug,
    Solid,
    Stripes,
    Television,
    Tiles,
    WallPaint,
    WindowView,
    WoodGrain,
)

ROOM_MIN: Tuple[float, float, float] = (-3.0, 0.0, -2.5)
ROOM_MAX: Tuple[float, float, float] = (3.0, 3.0, 2.5)


@dataclass(frozen=True)
class PointLight:
    """Isotropic light with a soft distance falloff `intensity / (1 + (d / falloff)^2)`."""

    position: Tuple[float, float, float]
    intensity: float
    falloff: float = 2.5


@dataclass(frozen=True)
class Room:
    """The scene: primitives plus a simple shadowless lighting model (ambient + Lambertian lights)."""

    primitives: Tuple[Primitive, ...]
    lights: Tuple[PointLight, ...]
    ambient: float
    sun_direction: Tuple[float, float, float]
    """Direction the window's fill light travels (unit vector)."""
    sun_intensity: float

    def primitive(self, name: str) -> Primitive:
        """The primitive called `name`."""
        for primitive in self.primitives:
            if primitive.name == name:
                return primitive
        raise KeyError(name)

    def shade(self, hits: RayHits) -> np.ndarray:
        """Linear RGB radiance in [0, 1] of each hit: albedo x light, or the albedo itself if emissive."""
        light = np.full(len(hits.t), self.ambient)
        for lamp in self.lights:
            to_light = np.asarray(lamp.position) - hits.position
            dist = np.linalg.norm(to_light, axis=1)
            cosine = np.einsum("ij,ij->i", hits.normal, to_light) / np.maximum(dist, 1e-6)
            light += lamp.intensity * np.clip(cosine, 0.0, None) / (1.0 + (dist / lamp.falloff) ** 2)
        light += self.sun_intensity * np.clip(-hits.normal @ np.asarray(self.sun_direction), 0.0, None)
        rgb = np.where(hits.emissive[:, None], hits.albedo, hits.albedo * light[:, None])
        return np.clip(rgb, 0.0, 1.0)


class _RoomBuilder:
    """Collects primitives; draws colour jitter and book widths from the seed's random generator."""

    def __init__(self, seed: int) -> None:
        self.rng = np.random.default_rng([seed, 0])
        self.primitives: List[Primitive] = []

    def color(self, rgb: RGB, amount: float = 0.08) -> RGB:
        jittered = np.clip(np.asarray(rgb) * (1.0 + self.rng.uniform(-amount, amount, 3)), 0.0, 1.0)
        return (float(jittered[0]), float(jittered[1]), float(jittered[2]))

    def add(self, name: str, shape: Shape, semantic: str, texture: Texture, emissive: bool = False) -> None:
        self.primitives.append(Primitive(name, shape, CLASS_ID[semantic], texture, emissive))

    def box(self, name: str, lo: Sequence[float], hi: Sequence[float], semantic: str, texture: Texture) -> None:
        self.add(name, Box(tuple(map(float, lo)), tuple(map(float, hi))), semantic, texture)

    def book_row(self, name: str, x0: float, x1: float, y0: float, height: float, z0: float, z1: float) -> None:
        """Books of random widths (5-11 cm) and colours filling x0..x1 on a shelf board at height y0."""
        edges = [0.0]
        while edges[-1] < x1 - x0 - 0.05:
            edges.append(min(edges[-1] + float(self.rng.uniform(0.05, 0.11)), x1 - x0))
        palette = [
            (0.7, 0.12, 0.1),
            (0.1, 0.25, 0.6),
            (0.12, 0.45, 0.2),
            (0.85, 0.7, 0.15),
            (0.45, 0.2, 0.5),
            (0.9, 0.9, 0.85),
            (0.2, 0.2, 0.22),
            (0.85, 0.45, 0.15),
        ]
        colors = [self.color(palette[i]) for i in self.rng.integers(0, len(palette), len(edges) - 1)]
        texture = Books(edges=tuple(edges), colors=tuple(colors))
        self.box(name, (x0, y0, z0), (x0 + edges[-1], y0 + height, z1), "books", texture)

    def chair(self, name: str, x0: float, x1: float, z0: float, z1: float, back_at_z0: bool, texture: Texture) -> None:
        """Chair with a seat at 0.43-0.47 m, four legs and a backrest on the z0 (or z1) side."""
        t = 0.04
        self.box(f"{name}_seat", (x0, 0.43, z0), (x1, 0.47, z1), "chair", texture)
        zb = z0 if back_at_z0 else z1 - t
        self.box(f"{name}_back", (x0, 0.47, zb), (x1, 0.95, zb + t), "chair", texture)
        for i, (lx, lz) in enumerate([(x0, z0), (x1 - t, z0), (x0, z1 - t), (x1 - t, z1 - t)]):
            self.box(f"{name}_leg{i}", (lx, 0.0, lz), (lx + t, 0.43, lz + t), "chair", texture)


def build_room(seed: int = 0) -> Room:
    """The furnished room; `seed` varies colours, book widths and painting cells, never the furniture layout."""
    b = _RoomBuilder(seed)
    c = b.color

    # Shell: floor, ceiling and four walls as boxes outside the room volume.
    b.box("floor", (-3.2, -0.2, -2.7), (3.2, 0.0, 2.7), "floor", Planks(c((0.62, 0.43, 0.26)), (0.25, 0.16, 0.1)))
    b.box("ceiling", (-3.2, 3.0, -2.7), (3.2, 3.2, 2.7), "ceiling", Tiles(c((0.92, 0.92, 0.88)), (0.6, 0.6, 0.58)))
    rail = (0.93, 0.92, 0.88)
    b.box("wall_left", (-3.2, 0, -2.7), (-3.0, 3.0, 2.7), "wall",
          WallPaint(c((0.82, 0.78, 0.62)), c((0.45, 0.55, 0.5)), rail, stripe=c((0.74, 0.68, 0.5))))
    b.box("wall_right", (3.0, 0, -2.7), (3.2, 3.0, 2.7), "wall",
          WallPaint(c((0.75, 0.82, 0.86)), c((0.35, 0.42, 0.55)), rail))
    b.box("wall_back", (-3.0, 0, -2.7), (3.0, 3.0, -2.5), "wall",
          WallPaint(c((0.86, 0.76, 0.7)), c((0.55, 0.35, 0.3)), rail))
    b.box("wall_front", (-3.0, 0, 2.5), (3.0, 3.0, 2.7), "wall",
          WallPaint(c((0.8, 0.84, 0.72)), c((0.4, 0.45, 0.3)), rail, stripe=c((0.7, 0.76, 0.62)), stripe_period=0.5))
    b.box("rug", (-1.6, 0.0, -0.9), (0.4, 0.012, 0.9), "floor",
          Rug(c((0.55, 0.12, 0.12)), c((0.85, 0.75, 0.55)), c((0.2, 0.3, 0.5))))
    for i, (x, z) in enumerate([(-0.6, 0.0), (1.6, -1.4)]):
        b.add(f"ceiling_lamp{i}", Cylinder(x, z, 0.22, 2.93, 3.0), "objects", Solid((1.0, 0.97, 0.88)), emissive=True)

    # Window and paintings on the walls.
    b.add("window", Box((2.97, 1.0, -0.2), (3.0, 2.3, 1.3)), "window", WindowView(front=(0, -1)), emissive=True)
    cells = [(0.95, 0.95, 0.92), (0.85, 0.1, 0.1), (0.1, 0.2, 0.7), (0.95, 0.8, 0.1), (0.95, 0.95, 0.92),
             (0.1, 0.1, 0.1), (0.95, 0.95, 0.92), (0.2, 0.6, 0.3), (0.95, 0.95, 0.92)]
    order = b.rng.permutation(len(cells))
    b.box("painting_back", (-0.95, 1.2, -2.5), (0.45, 2.05, -2.47), "painting",
          Mondrian(cells=tuple(c(cells[i]) for i in order), front=(2, 1)))
    b.box("painting_left", (-3.0, 1.25, -0.7), (-2.97, 1.95, 0.5), "painting",
          Landscape(c((0.55, 0.75, 0.95)), (0.98, 0.75, 0.2), c((0.35, 0.4, 0.45)), c((0.15, 0.35, 0.6)), front=(0, 1)))

    # Bed with headboard, duvet and pillows against the back wall; nightstand with a vase.
    wood_dark = c((0.4, 0.26, 0.16))
    b.box("bed_frame", (0.9, 0, -2.45), (2.5, 0.3, -0.45), "bed", WoodGrain(wood_dark, axis=2))
    b.box("bed_headboard", (0.9, 0, -2.5), (2.5, 1.1, -2.42), "bed",
          Cabinet(wood_dark, front=(2, 1), cols=3, rows=1, handle=None, gap_width=0.02))
    b.box("bed_mattress", (0.95, 0.3, -2.4), (2.45, 0.5, -0.5), "bed", Solid(c((0.92, 0.92, 0.9))))
    b.box("bed_duvet", (0.92, 0.3, -1.7), (2.48, 0.56, -0.47), "bed",
          Stripes((c((0.2, 0.35, 0.65)), c((0.9, 0.9, 0.88)), c((0.75, 0.3, 0.25))), period=0.16, axis=2))
    b.box("bed_pillow0", (1.05, 0.5, -2.35), (1.6, 0.64, -1.95), "bed", Solid(c((0.95, 0.95, 0.95))))
    b.box("bed_pillow1", (1.8, 0.5, -2.35), (2.35, 0.64, -1.95), "bed", Solid(c((0.95, 0.88, 0.6))))
    b.box("nightstand", (2.55, 0, -2.5), (2.98, 0.55, -2.1), "furniture",
          Cabinet(c((0.75, 0.6, 0.4)), front=(2, 1), cols=1, rows=2))
    b.add("nightstand_vase", Cylinder(2.76, -2.3, 0.07, 0.55, 0.8), "objects",
          Stripes((c((0.2, 0.5, 0.7)), c((0.95, 0.95, 0.9))), period=0.05, axis=1))

    # Bookshelf with four rows of books in the back-left corner.
    shelf = WoodGrain(c((0.7, 0.52, 0.32)), axis=0)
    b.box("shelf_back", (-2.7, 0, -2.5), (-1.3, 2.0, -2.47), "furniture", shelf)
    b.box("shelf_side0", (-2.7, 0, -2.5), (-2.66, 2.0, -2.15), "furniture", shelf)
    b.box("shelf_side1", (-1.34, 0, -2.5), (-1.3, 2.0, -2.15), "furniture", shelf)
    boards = [0.0, 0.5, 1.0, 1.5, 1.96]
    for i, y in enumerate(boards):
        b.box(f"shelf_board{i}", (-2.66, y, -2.47), (-1.34, y + 0.04, -2.15), "furniture", shelf)
    for i, (y, height, x0, x1) in enumerate(
        [(0.04, 0.3, -2.66, -1.45), (0.54, 0.26, -2.5, -1.34), (1.04, 0.32, -2.66, -1.7), (1.54, 0.28, -2.66, -1.5)]
    ):
        b.book_row(f"books{i}", x0, x1, y, height, -2.45, -2.2)

    # Sofa against the left wall.
    fabric = Checker(c((0.3, 0.45, 0.4)), c((0.2, 0.32, 0.3)), size=0.15)
    b.box("sofa_base", (-2.95, 0, -1.0), (-2.1, 0.42, 0.9), "sofa", fabric)
    b.box("sofa_back", (-2.95, 0.42, -1.0), (-2.7, 0.95, 0.9), "sofa", fabric)
    arm = Solid(c((0.18, 0.27, 0.25)))
    b.box("sofa_arm0", (-2.95, 0, -1.2), (-2.1, 0.65, -1.0), "sofa", arm)
    b.box("sofa_arm1", (-2.95, 0, 0.9), (-2.1, 0.65, 1.1), "sofa", arm)

    # TV on a stand against the front wall, with a vase.
    b.box("tv_stand", (-1.5, 0, 2.1), (0.1, 0.5, 2.5), "furniture",
          Cabinet(c((0.3, 0.3, 0.32)), front=(2, -1), cols=3, rows=1))
    b.box("tv", (-1.2, 0.8, 2.38), (-0.2, 1.4, 2.45), "tv", Television(front=(2, -1)))
    b.box("tv_foot", (-0.8, 0.5, 2.3), (-0.6, 0.8, 2.42), "tv", Solid((0.1, 0.1, 0.11)))
    b.add("tv_vase", Cylinder(-1.38, 2.3, 0.06, 0.5, 0.78), "objects",
          Stripes((c((0.8, 0.3, 0.2)), c((0.95, 0.85, 0.6))), period=0.07, axis=1))

    # Table with two chairs near the window, a vase and a fruit on it.
    table = WoodGrain(c((0.6, 0.4, 0.22)), axis=0)
    b.box("table_top", (1.2, 0.72, 0.3), (2.2, 0.77, 1.2), "table", table)
    for i, (x, z) in enumerate([(1.24, 0.34), (2.1, 0.34), (1.24, 1.1), (2.1, 1.1)]):
        b.box(f"table_leg{i}", (x, 0, z), (x + 0.06, 0.72, z + 0.06), "table", table)
    chair = WoodGrain(c((0.65, 0.2, 0.15)), axis=1)
    b.chair("chair0", 1.47, 1.93, -0.2, 0.25, back_at_z0=True, texture=chair)
    b.chair("chair1", 1.47, 1.93, 1.25, 1.7, back_at_z0=False, texture=chair)
    b.add("table_vase", Cylinder(1.55, 0.75, 0.07, 0.77, 1.05), "objects",
          Stripes((c((0.9, 0.9, 0.85)), c((0.1, 0.3, 0.6)), c((0.9, 0.6, 0.1))), period=0.06, axis=1))
    b.add("table_fruit", Sphere((1.9, 0.84, 0.8), 0.07), "objects", Solid(c((0.95, 0.5, 0.1))))

    # Wardrobe in the front-right corner with a storage box on top.
    b.box("wardrobe", (2.05, 0, 2.0), (2.95, 2.1, 2.5), "furniture",
          Cabinet(c((0.85, 0.82, 0.75)), front=(2, -1), cols=2, rows=1, gap=(0.35, 0.33, 0.3)))
    b.box("wardrobe_box", (2.2, 2.1, 2.1), (2.6, 2.35, 2.4), "objects",
          Stripes((c((0.7, 0.55, 0.35)), c((0.55, 0.4, 0.25))), period=0.1, axis=0))

    # Potted plant in the front-left corner, a beach ball on the floor.
    b.add("plant_pot", Cylinder(-2.65, 2.2, 0.18, 0.0, 0.4), "objects",
          Stripes((c((0.7, 0.35, 0.2)), c((0.55, 0.25, 0.15))), period=0.1, axis=1))
    b.add("plant_leaves", Sphere((-2.65, 0.75, 2.2), 0.35), "objects",
          Stripes((c((0.2, 0.5, 0.2)), c((0.12, 0.35, 0.12))), period=0.08, axis=1))
    b.add("ball", Sphere((-1.9, 0.15, 1.7), 0.15), "objects",
          BeachBall((c((0.9, 0.15, 0.1)), c((0.95, 0.85, 0.1)), c((0.1, 0.4, 0.85)))))

    # Detail where the room was plainest (the front wall between the TV and the wardrobe, the corner by the shelf):
    # a painting, a coat rack and a floor lamp, with thin parts and curved shapes.
    b.box("painting_front", (0.3, 1.3, 2.47), (0.9, 1.9, 2.5), "painting",
          Landscape(c((0.85, 0.7, 0.55)), (0.95, 0.95, 0.8), c((0.3, 0.5, 0.3)), c((0.5, 0.3, 0.2)), front=(2, -1)))
    metal = Solid(c((0.2, 0.2, 0.22)))
    b.add("coat_rack_pole", Cylinder(1.35, 2.3, 0.025, 0.0, 1.75), "objects", WoodGrain(c((0.45, 0.3, 0.18)), axis=1))
    b.add("coat_rack_foot", Cylinder(1.35, 2.3, 0.2, 0.0, 0.03), "objects", metal)
    for i, (dx, height) in enumerate(((-0.08, 1.62), (0.08, 1.52), (0.0, 1.76))):
        b.add(f"coat_rack_hook{i}", Sphere((1.35 + dx, height, 2.3), 0.04), "objects", metal)
    b.add("floor_lamp_pole", Cylinder(-2.6, -1.65, 0.02, 0.0, 1.5), "objects", metal)
    b.add("floor_lamp_foot", Cylinder(-2.6, -1.65, 0.15, 0.0, 0.03), "objects", metal)
    b.add("floor_lamp_shade", Sphere((-2.6, 1.62, -1.65), 0.17), "objects",
          Stripes((c((0.95, 0.9, 0.75)), c((0.85, 0.75, 0.55))), period=0.05, axis=1))

    return Room(
        primitives=tuple(b.primitives),
        lights=(PointLight((-0.6, 2.8, 0.0), 0.7), PointLight((1.6, 2.8, -1.4), 0.7)),
        ambient=0.4,
        sun_direction=(-0.894, -0.447, 0.0),
        sun_intensity=0.2,
    )
