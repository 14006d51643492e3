"""Camera paths in nerfstudio's viewer format (`camera_paths/*.json`), for `ns-render camera-path` and the viewer's
render panel.

nerfstudio reads a path's poses in the model's world frame, i.e. after the dataparser has oriented, centred and
scaled the dataset's poses; `to_model_frame` applies that same transform to poses given in the dataset's frame.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Sequence

import numpy as np
from jaxtyping import Float

from nerfstudio.data.dataparsers.base_dataparser import DataparserOutputs

from ssnerf_method.data.io import write_json_atomic


def to_model_frame(
    poses: Float[np.ndarray, "n 4 4"], outputs: DataparserOutputs
) -> Float[np.ndarray, "n 4 4"]:
    """Camera-to-world poses of the dataset's frame moved into the model's (the dataparser's transform and scale)."""
    transform = np.eye(4)
    transform[:3] = outputs.dataparser_transform.numpy()
    moved = transform @ np.asarray(poses, dtype=np.float64)
    moved[:, :3, 3] *= float(outputs.dataparser_scale)
    return moved


def write_camera_path(
    path: Path, poses: Sequence[np.ndarray], width: int, height: int, fy: float, seconds: float
) -> Path:
    """Write poses already in the model's frame (OpenGL camera-to-world) as a nerfstudio camera path of
    `width` x `height` frames with focal length `fy` (pixels), played over `seconds`."""
    fov = math.degrees(2.0 * math.atan(height / 2.0 / fy))  # three.js: vertical field of view in degrees
    keyframes = [
        {"camera_to_world": np.asarray(pose, dtype=np.float64).reshape(-1).tolist(), "fov": fov,
         "aspect": width / height}
        for pose in poses
    ]
    content = {
        "camera_type": "perspective", "render_height": height, "render_width": width, "camera_path": keyframes,
        "fps": len(keyframes) / seconds, "seconds": seconds, "smoothness_value": 0.0, "is_cycle": False, "crop": None,
    }
    write_json_atomic(path, content)
    return path
