"""Replica's semantic class names mapped to the NYUv2-13 classes SS-NeRF trains on.

Each Replica class name (its habitat `info_semantic.json`) is first given the NYU-40 class it corresponds to, then
the standard NYU-40 -> NYU-13 grouping (Couprie et al. 2013, the `class13Mapping` shipped with the NYUv2 toolbox)
gives its NYU-13 class. Keeping the two steps apart keeps every choice checkable against the published grouping.
"""

from __future__ import annotations

from ssnerf_method.data.classes import SEMANTIC_CLASSES

VOID = SEMANTIC_CLASSES[0]
"""Class 0 of the NYU-13 list: no label."""

NYU40_CLASSES: tuple[str, ...] = (
    "wall", "floor", "cabinet", "bed", "chair", "sofa", "table", "door", "window", "bookshelf",
    "picture", "counter", "blinds", "desk", "shelves", "curtain", "dresser", "pillow", "mirror", "floor mat",
    "clothes", "ceiling", "books", "refrigerator", "television", "paper", "towel", "shower curtain", "box",
    "whiteboard", "person", "night stand", "toilet", "sink", "lamp", "bathtub", "bag", "otherstructure",
    "otherfurniture", "otherprop",
)  # fmt: skip
"""The NYU-40 classes, ids 1..40 in order."""

NYU40_TO_NYU13_ID: tuple[int, ...] = (
    12, 5, 6, 1, 4, 9, 10, 12, 13, 6, 8, 6, 13, 10, 6, 13, 6, 7, 7, 5,
    7, 3, 2, 6, 11, 7, 7, 7, 7, 7, 7, 6, 7, 7, 7, 7, 7, 7, 6, 7,
)  # fmt: skip
"""The standard grouping: NYU-13 id (1 bed, 2 books, ... 13 window, as in `SEMANTIC_CLASSES`) of each NYU-40 class."""

NYU40_TO_NYU13: dict[str, str] = {
    name: SEMANTIC_CLASSES[index] for name, index in zip(NYU40_CLASSES, NYU40_TO_NYU13_ID)
}
"""NYU-40 class name -> NYU-13 class name."""

REPLICA_TO_NYU40: dict[str, str] = {
    # structure
    "wall": "wall", "door": "door", "floor": "floor", "ceiling": "ceiling", "window": "window",
    "rug": "floor mat", "mat": "floor mat", "blinds": "blinds", "curtain": "curtain",
    "beam": "otherstructure", "pillar": "otherstructure", "handrail": "otherstructure", "stair": "otherstructure",
    "panel": "otherstructure", "pipe": "otherstructure", "vent": "otherstructure", "shower-stall": "otherstructure",
    # furniture
    "bed": "bed", "comforter": "bed", "chair": "chair", "stool": "chair", "bench": "chair", "beanbag": "chair",
    "sofa": "sofa", "table": "table", "desk": "desk", "countertop": "counter",
    "cabinet": "cabinet", "base-cabinet": "cabinet", "wall-cabinet": "cabinet", "shelf": "shelves",
    "nightstand": "night stand", "wardrobe": "otherfurniture", "tv-stand": "otherfurniture",
    "rack": "otherfurniture", "plant-stand": "otherfurniture", "major-appliance": "otherfurniture",
    "refrigerator": "refrigerator",
    # things with an NYU-40 class of their own
    "book": "books", "books": "books", "picture": "picture", "tv-screen": "television", "monitor": "television",
    "pillow": "pillow", "cushion": "pillow", "lamp": "lamp", "box": "box", "towel": "towel", "sink": "sink",
    "toilet": "toilet", "bathtub": "bathtub", "bag": "bag", "backpack": "bag", "handbag": "bag",
    "cloth": "clothes", "clothing": "clothes", "set-of-clothing": "clothes", "scarf": "clothes",
    "paper-towel": "paper", "tissue-paper": "paper",
    # small things
    "basket": "otherprop", "bike": "otherprop", "bin": "otherprop", "blanket": "otherprop", "bottle": "otherprop",
    "bowl": "otherprop", "camera": "otherprop", "candle": "otherprop", "chopping-board": "otherprop",
    "clock": "otherprop", "coaster": "otherprop", "computer-keyboard": "otherprop", "cooktop": "otherprop",
    "cup": "otherprop", "desk-organizer": "otherprop", "desktop-computer": "otherprop", "exercise-ball": "otherprop",
    "faucet": "otherprop", "hair-dryer": "otherprop", "indoor-plant": "otherprop", "kitchen-utensil": "otherprop",
    "knife-block": "otherprop", "laptop": "otherprop", "logo": "otherprop", "microwave": "otherprop",
    "mouse": "otherprop", "pan": "otherprop", "phone": "otherprop", "plate": "otherprop", "pot": "otherprop",
    "remote-control": "otherprop", "sculpture": "otherprop", "shoe": "otherprop", "small-appliance": "otherprop",
    "switch": "otherprop", "table-runner": "otherprop", "tablet": "otherprop", "toothbrush": "otherprop",
    "umbrella": "otherprop", "utensil-holder": "otherprop", "vase": "otherprop", "wall-plug": "otherprop",
}  # fmt: skip
"""Replica class name -> NYU-40 class name (Replica's names are lower case, words joined by '-')."""

REPLICA_VOID_NAMES: tuple[str, ...] = ("undefined", "void", "unknown", "unlabeled", "unlabelled")
"""Replica names (and spellings of them) for pixels with no class."""

REPLICA_TO_NYU13: dict[str, str] = {
    **{name: NYU40_TO_NYU13[nyu40] for name, nyu40 in REPLICA_TO_NYU40.items()},
    **{name: VOID for name in REPLICA_VOID_NAMES},
}
"""Replica class name -> NYU-13 class name (or "void")."""

FALLBACK_CLASS = "objects"
"""NYU-13 class of a Replica name missing from the table (most unlisted Replica classes are small props)."""


def replica_to_nyu13(name: str) -> tuple[str, bool]:
    """NYU-13 class of a Replica class name, and whether the name was in the table (else `FALLBACK_CLASS`)."""
    key = name.strip().lower().replace(" ", "-").replace("_", "-")
    if key in REPLICA_TO_NYU13:
        return REPLICA_TO_NYU13[key], True
    return FALLBACK_CLASS, False
