"""How far a dataset's test views are from its training views: what decides how much a label warp (the Heuristic)
can get right, and so how hard a benchmark scene is."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Dict, Optional, Sequence

import numpy as np
from jaxtyping import Float

ANGLE_WEIGHT = 0.5
"""Scene units (metres here) per radian of viewing angle when ranking training views by nearness: the
Heuristic's default (`evaluation/heuristic.py`) and this module's statistic."""


def pose_spacing(train: Float[np.ndarray, "n 4 4"], test: Float[np.ndarray, "m 4 4"]) -> Dict[str, Optional[float]]:
    """Median over test views of the distance (metres) and angle (degrees) to the nearest training view, nearest by
    camera-centre distance + `ANGLE_WEIGHT` x the angle between viewing directions (camera-to-world, OpenGL)."""
    if len(train) == 0 or len(test) == 0:
        return {"median_m": None, "median_deg": None, "test_views": len(test)}
    centres = train[:, :3, 3]
    forwards = -train[:, :3, 2]
    distances, angles = [], []
    for pose in test:
        distance = np.linalg.norm(centres - pose[:3, 3], axis=1)
        angle = np.arccos(np.clip(forwards @ -pose[:3, 2], -1.0, 1.0))
        nearest = int(np.argmin(distance + ANGLE_WEIGHT * angle))
        distances.append(distance[nearest])
        angles.append(np.degrees(angle[nearest]))
    return {"median_m": float(np.median(distances)), "median_deg": float(np.median(angles)), "test_views": len(test)}


def split_poses(meta: Dict, names: Sequence[str]) -> np.ndarray:
    """(k, 4, 4) transform matrices of the frames whose image is named in `names` (by file name, so that the absolute
    paths of a k-view copy's split lists match too), in the file's order."""
    wanted = {Path(name).name for name in names}
    return np.array([frame["transform_matrix"] for frame in meta["frames"]
                     if Path(frame["file_path"]).name in wanted], dtype=np.float64).reshape(-1, 4, 4)


def dataset_spacing(root: Path) -> Dict[str, Optional[float]]:
    """`pose_spacing` of a dataset's test split against its training split: the splits as the dataparser makes them
    (split lists, or nerfstudio's rule without them), the poses as `transforms.json` holds them (metres)."""
    from ssnerf_method.data.dataparser import SSNeRFDataParserConfig  # the parser imports nerfstudio's data stack

    parser = SSNeRFDataParserConfig(data=root).setup()
    names = {split: [str(name) for name in parser.get_dataparser_outputs(split).image_filenames]
             for split in ("train", "test")}
    meta = json.loads((root / "transforms.json").read_text())
    return pose_spacing(split_poses(meta, names["train"]), split_poses(meta, names["test"]))
