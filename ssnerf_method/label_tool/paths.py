"""Where `ssnerf-label` puts things: each frame's label files, the transforms file it writes, and file paths moved
when that file goes elsewhere."""

from __future__ import annotations

import os
from pathlib import Path, PurePosixPath
from typing import Dict, Optional

from ssnerf_method.data.transforms import Transforms
from ssnerf_method.properties import REGISTRY

LABEL_FOLDER = "ssnerf_labels"
"""Folder, inside the dataset, that `ssnerf-label` owns: it only ever writes there (and the transforms file)."""

SPLIT_KEYS = ("train_filenames", "val_filenames", "test_filenames")
"""Top-level transforms keys that list image paths (rewritten with the frames' when the output moves)."""


def label_path(frame: Dict, name: str) -> PurePosixPath:
    """Where a frame's label goes, relative to the dataset: `ssnerf_labels/<name>/<image path>.png`, without the
    image path's leading `images/` (nerfstudio's usual folder); other folders are kept so that names stay unique."""
    parts = [part for part in PurePosixPath(frame["file_path"]).parts if part not in (".", "")]
    if len(parts) > 1 and parts[0] == "images":
        parts = parts[1:]
    return PurePosixPath(LABEL_FOLDER, name, *parts).with_suffix(".png")


def output_path(output: Optional[str], transforms: Transforms) -> Path:
    """The transforms file `ssnerf-label` writes: the dataset's own, a new name beside it, or a path elsewhere."""
    if output is None:
        return transforms.path
    given = Path(output)
    return given if given.is_absolute() or given.parent != Path(".") else transforms.folder / given


def rebase_paths(meta: Dict, source: Path, target: Path) -> Dict:
    """A copy of `meta` with every file path of its frames and splits made relative to `target` instead of `source`."""
    if source.resolve() == target.resolve():
        return dict(meta)

    def moved(value: str) -> str:
        return os.path.relpath(source / value, target)

    keys = ["file_path", "depth_file_path", "mask_path",
            *[spec.file_key for spec in REGISTRY.values() if spec.file_key]]
    frames = [{key: moved(value) if key in keys and isinstance(value, str) else value for key, value in frame.items()}
              for frame in meta["frames"]]
    splits = {key: [moved(value) for value in meta[key]] for key in SPLIT_KEYS if key in meta}
    return {**meta, **splits, "frames": frames}
