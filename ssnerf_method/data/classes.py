"""The semantic classes of the generated scenes and of the importers: NYUv2-13 (the paper's label set) plus void."""

from __future__ import annotations

from typing import Tuple

SEMANTIC_CLASSES: Tuple[str, ...] = (
    "void",
    "bed",
    "books",
    "ceiling",
    "chair",
    "floor",
    "furniture",
    "objects",
    "painting",
    "sofa",
    "table",
    "tv",
    "wall",
    "window",
)
"""NYUv2-13 classes plus void; a class id is its index."""

SEMANTIC_COLORS: Tuple[Tuple[int, int, int], ...] = (
    (0, 0, 0),
    (174, 199, 232),
    (31, 119, 180),
    (255, 187, 120),
    (188, 189, 34),
    (140, 86, 75),
    (255, 152, 150),
    (214, 39, 40),
    (197, 176, 213),
    (148, 103, 189),
    (196, 156, 148),
    (23, 190, 207),
    (178, 76, 76),
    (247, 182, 210),
)
"""One distinct display colour (0-255 RGB) per class, in `SEMANTIC_CLASSES` order."""

CLASS_ID = {name: index for index, name in enumerate(SEMANTIC_CLASSES)}
