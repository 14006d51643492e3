"""The class list `ssnerf-label` writes (`semantic_classes`, id = index) and its display colours (`semantic_colors`).

Annotation tools name classes; the dataset numbers them. Names a source uses are matched to the dataset's list and
new ones appended after it, so ids already in label files keep their meaning; `--semantic-classes` fixes the list
instead, and a name outside it is an error. A dataset that lists colours gets one for each appended class: the
colour the model would show that class in without one (`rendering/palette.py`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Dict, List, Optional, Sequence

from ssnerf_method.data.io import DatasetInputError
from ssnerf_method.label_makers.encoding import SEMANTIC_IGNORE
from ssnerf_method.rendering.palette import default_palette


def class_list(existing: Sequence[str], fixed: Optional[Sequence[str]], used: Sequence[str], source: Path,
               declared: Sequence[str] = ()) -> List[str]:
    """The classes after importing a source that uses the names `used` (and declares `declared`, e.g. COCO's
    categories): `fixed` when given (every used name must be in it), else `existing` plus the new names, used and
    declared, in the source's order."""
    if fixed:
        outside = [name for name in used if name not in fixed]
        if outside:
            raise DatasetInputError(
                f"{source}: class {outside[0]!r} is not in --semantic-classes ({', '.join(fixed)}). Add it to "
                "--semantic-classes, or rename it in the annotations."
            )
        names = list(fixed)
    else:
        names = list(existing)
        names += [name for name in dict.fromkeys([*declared, *used]) if name not in names]
    if len(names) > SEMANTIC_IGNORE:
        raise DatasetInputError(
            f"{source}: {len(names)} classes, but label files hold ids 0-{SEMANTIC_IGNORE - 1} ({SEMANTIC_IGNORE} = "
            "unlabelled). Merge classes, or fix the class names with --semantic-classes."
        )
    return names


def class_colors(colors: Optional[Sequence[Sequence[int]]], num_classes: int) -> Optional[List[List[int]]]:
    """`colors` (0-255 triples) made one per class: kept for the classes they exist for, the palette's colour for the
    others; None when the dataset lists no colours (the model then uses the palette for every class)."""
    if colors is None:
        return None
    palette = (default_palette(num_classes) * 255).round().int().tolist()
    return [list(colors[index]) if index < len(colors) else palette[index] for index in range(num_classes)]


def class_record(meta: Dict, names: List[str]) -> Dict:
    """The top-level keys that list `names` as the dataset's classes (with colours when it has them)."""
    record: Dict = {"semantic_classes": names}
    colors = class_colors(meta.get("semantic_colors"), len(names))
    if colors is not None:
        record["semantic_colors"] = colors
    return record
