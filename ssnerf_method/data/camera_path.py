"""Camera paths in nerfstudio's viewer format (`camera_paths/*.json`), for `ns-render camera-path` and the viewer's
render panel; and new poses between given ones (`interpolate_poses`).

nerfstudio reads a path's poses in the model's world frame, i.e. after the dataparser has oriented, centred and
scaled the dataset's poses; `to_model_frame` applies that same transform to poses given in the dataset's frame.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Sequence

import numpy as np
from jaxtyping import Float
from scipy.spatial.transform import Rotation, Slerp

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


def interpolate_poses(
    first: Float[np.ndarray, "3 4"], second: Float[np.ndarray, "3 4"], fractions: Sequence[float]
) -> Float[np.ndarray, "n 3 4"]:
    """Camera-to-world poses at `fractions` of the way from `first` to `second`: camera centres on the straight line,
    orientations by spherical interpolation (proper rotations; 0.5 is the paper's "average of adjacent poses")."""
    rotations = Rotation.from_matrix(np.stack([first[:3, :3], second[:3, :3]]))
    between = Slerp([0.0, 1.0], rotations)(np.asarray(fractions, dtype=np.float64)).as_matrix()
    weights = np.asarray(fractions, dtype=np.float64)[:, None]
    centres = (1.0 - weights) * first[:3, 3] + weights * second[:3, 3]
    return np.concatenate([between, centres[:, :, None]], axis=-1)
