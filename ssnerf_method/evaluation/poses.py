"""How far recovered camera poses are from the true ones, up to the similarity that structure from motion cannot know
(its world's origin, rotation and scale): camera centres aligned by Umeyama's least squares, then per-camera rotation
angle and centre distance."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Tuple

import numpy as np
from jaxtyping import Float


@dataclass
class PoseErrors:
    """Per-camera errors after the alignment."""

    rotation_deg: Float[np.ndarray, " n"]
    """Angle between each true camera rotation and the aligned recovered one."""
    translation: Float[np.ndarray, " n"]
    """Distance between each true camera centre and the aligned recovered one, as a share of `scene_size`."""
    scene_size: float
    """Diagonal of the true camera centres' bounding box (the scale the distances are divided by)."""


def similarity(source: Float[np.ndarray, "n 3"], target: Float[np.ndarray, "n 3"]
               ) -> Tuple[float, Float[np.ndarray, "3 3"], Float[np.ndarray, "3"]]:
    """(scale, rotation, translation) minimising |scale * rotation @ source + translation - target|^2 (Umeyama)."""
    mean_source, mean_target = source.mean(axis=0), target.mean(axis=0)
    centred_source, centred_target = source - mean_source, target - mean_target
    covariance = centred_target.T @ centred_source / len(source)
    u, singular, vt = np.linalg.svd(covariance)
    sign = np.eye(3)
    sign[2, 2] = np.sign(np.linalg.det(u @ vt)) or 1.0
    rotation = u @ sign @ vt
    scale = float(np.trace(np.diag(singular) @ sign) / centred_source.var(axis=0).sum())
    return scale, rotation, mean_target - scale * rotation @ mean_source


def pose_errors(true_c2w: Float[np.ndarray, "n 4 4"], recovered_c2w: Float[np.ndarray, "n 4 4"]) -> PoseErrors:
    """Errors of `recovered_c2w` against `true_c2w` (same cameras, same order; same camera axes convention)."""
    scale, rotation, translation = similarity(recovered_c2w[:, :3, 3], true_c2w[:, :3, 3])
    centres = scale * recovered_c2w[:, :3, 3] @ rotation.T + translation
    aligned = rotation @ recovered_c2w[:, :3, :3]
    relative = np.einsum("nji,njk->nik", true_c2w[:, :3, :3], aligned)
    cosine = np.clip((np.trace(relative, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    extent = true_c2w[:, :3, 3].max(axis=0) - true_c2w[:, :3, 3].min(axis=0)
    size = float(np.linalg.norm(extent))
    return PoseErrors(rotation_deg=np.degrees(np.arccos(cosine)),
                      translation=np.linalg.norm(centres - true_c2w[:, :3, 3], axis=1) / size, scene_size=size)


def poses_by_photo_order(true_transforms: Path, recovered_transforms: Path
                         ) -> Tuple[Float[np.ndarray, "n 4 4"], Float[np.ndarray, "n 4 4"]]:
    """Stacked true and recovered camera-to-world poses of the frames `ssnerf-process` posed: its `frame_00001` is the
    first photo in name order, so the k-th true frame (by file name) is its `frame_{k+1:05d}`."""
    truth = sorted(json.loads(true_transforms.read_text())["frames"], key=lambda frame: frame["file_path"])
    recovered = json.loads(recovered_transforms.read_text())["frames"]
    index = [int(Path(frame["file_path"]).stem.split("_")[1]) - 1 for frame in recovered]
    return (np.stack([np.asarray(truth[i]["transform_matrix"], dtype=np.float64) for i in index]),
            np.stack([np.asarray(frame["transform_matrix"], dtype=np.float64) for frame in recovered]))
