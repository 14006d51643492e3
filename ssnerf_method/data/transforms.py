"""A nerfstudio `transforms.json` as the dataset tools read it: its frames, each frame's camera and its pixel rays.

Cameras are built with nerfstudio's own `Cameras` (per-frame intrinsics overriding the top-level ones, distortion
parameters read the way nerfstudio's dataparser reads them), so labels derived from depth use the same rays nerfstudio
trains on. A file that cannot be parsed raises one `DatasetInputError` naming it and what to do; `validate.py` checks
the rest.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Tuple

import numpy as np
import torch
from jaxtyping import Float

from nerfstudio.cameras import camera_utils
from nerfstudio.cameras.cameras import CAMERA_MODEL_TO_TYPE, Cameras, CameraType

from ssnerf_method.data.io import DatasetInputError, image_size

INTRINSIC_KEYS = ("fl_x", "fl_y", "cx", "cy", "w", "h")
"""Intrinsics every frame needs, per frame or at the top level."""
DISTORTION_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")
"""nerfstudio's named distortion keys (`distortion_params` lists them in this order)."""


@dataclass(frozen=True)
class Transforms:
    """A dataset folder and its parsed transforms file."""

    folder: Path
    path: Path
    meta: Dict

    @property
    def frames(self) -> List[Dict]:
        return self.meta["frames"]

    def file(self, relative: str) -> Path:
        """A frame's file path, resolved against the dataset folder as nerfstudio does."""
        return self.folder / relative


def load_transforms(data: Path) -> Transforms:
    """Parse `data/transforms.json` (or `data` itself when it is a .json file); `data/validate.py` checks it."""
    if data.suffix == ".json" and data.is_file():
        folder, path = data.parent, data
    elif data.is_dir():
        folder, path = data, data / "transforms.json"
        if not path.is_file() and (data / "transforms_train.json").is_file():
            return Transforms(folder, path, blender_as_nerfstudio(folder))
        if not path.is_file():
            raise DatasetInputError(
                f"{path}: missing. Point at a nerfstudio dataset folder (with a transforms.json, e.g. the output of "
                "`ns-process-data images|video`), or import the data first (`ssnerf-import`, see docs/own-data.md)."
            )
    else:
        raise DatasetInputError(f"{data}: not a folder. Point at the dataset folder that holds transforms.json.")
    try:
        meta = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise DatasetInputError(f"{path}: not valid JSON ({err}). Restore its backup or regenerate it.") from err
    if not isinstance(meta, dict) or not isinstance(meta.get("frames"), list) or not meta["frames"]:
        raise DatasetInputError(f"{path}: has no \"frames\" list. It is not a nerfstudio transforms file.")
    return Transforms(folder, path, meta)


BLENDER_SPLITS = ("train", "val", "test")


def blender_as_nerfstudio(folder: Path) -> Dict:
    """The nerfstudio-format transforms of a Blender-synthetic folder (`transforms_{train,val,test}.json`).

    Read as nerfstudio's `blender-data` parser reads it: `file_path` plus ".png", OpenGL camera-to-world, focal length
    from `camera_angle_x` and the first image's width, principal point at the centre; the three files give the split.
    """
    frames, splits = [], {}
    angle = None
    for split in BLENDER_SPLITS:
        path = folder / f"transforms_{split}.json"
        if not path.is_file():
            continue
        try:
            meta = json.loads(path.read_text())
            angle = float(meta["camera_angle_x"])
            split_frames = [(frame["file_path"], frame["transform_matrix"]) for frame in meta["frames"]]
        except (OSError, ValueError, KeyError, TypeError) as err:
            raise DatasetInputError(
                f"{path}: not a Blender transforms file (needs camera_angle_x and frames with file_path and "
                f"transform_matrix; {err!r}). Fix the file or convert the data with ns-process-data."
            ) from err
        splits[f"{split}_filenames"] = []
        for file_path, matrix in split_frames:
            relative = file_path.removeprefix("./")
            relative += "" if Path(relative).suffix else ".png"
            frames.append({"file_path": relative, "transform_matrix": matrix})
            splits[f"{split}_filenames"].append(relative)
    if not frames:
        raise DatasetInputError(f"{folder / 'transforms_train.json'}: lists no frames. Point at a dataset with frames.")
    width, height = image_size(folder / frames[0]["file_path"], "image")
    focal = 0.5 * width / np.tan(0.5 * angle)
    intrinsics = {"fl_x": focal, "fl_y": focal, "cx": width / 2.0, "cy": height / 2.0, "w": width, "h": height}
    return {"camera_model": "OPENCV", **intrinsics, **splits, "ssnerf_converted_from": "blender", "frames": frames}


def frame_camera(transforms: Transforms, frame: Dict) -> Cameras:
    """The nerfstudio camera of one frame, at the identity pose (so its rays are in the camera frame)."""
    meta = transforms.meta

    def value(key: str, default: float = 0.0) -> float:
        return float(frame.get(key, meta.get(key, default)))

    model = frame.get("camera_model", meta.get("camera_model", "OPENCV"))
    if "distortion_params" in frame or "distortion_params" in meta:
        distortion = torch.tensor(frame.get("distortion_params", meta.get("distortion_params")), dtype=torch.float32)
    else:
        distortion = camera_utils.get_distortion_params(**{key: value(key) for key in DISTORTION_KEYS})
    return Cameras(
        camera_to_worlds=torch.eye(4)[None, :3],
        fx=value("fl_x"),
        fy=value("fl_y"),
        cx=value("cx"),
        cy=value("cy"),
        width=int(value("w")),
        height=int(value("h")),
        distortion_params=distortion[None],
        camera_type=CAMERA_MODEL_TO_TYPE[model],
    )


def camera_key(camera: Cameras) -> Tuple:
    """Hashable identity of a camera's intrinsics (frames sharing it share rays)."""
    return (
        int(camera.camera_type.item()),
        *(float(getattr(camera, name).item()) for name in ("fx", "fy", "cx", "cy")),
        int(camera.width.item()),
        int(camera.height.item()),
        *(camera.distortion_params.flatten().tolist() if camera.distortion_params is not None else []),
    )


def is_perspective(camera: Cameras) -> bool:
    return int(camera.camera_type.item()) == CameraType.PERSPECTIVE.value


def camera_rays(camera: Cameras) -> Float[np.ndarray, "height width 3"]:
    """Unit ray directions through every pixel centre in the camera frame (OpenGL axes), as nerfstudio casts them."""
    with torch.no_grad():
        rays = camera.generate_rays(camera_indices=0, keep_shape=True)
    return rays.directions.numpy().astype(np.float64)
