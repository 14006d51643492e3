"""z-depth rendered by a trained SS-NeRF at a dataset's frames, for `ssnerf-label --depth-from CONFIG`.

So captures without depth get normals and shading as from sensor depth. Each pose is moved into the model's frame as
the dataparser moved the training poses (undoing `applied_transform` / `applied_scale`); depth is in the file's units.
"""

from __future__ import annotations

import json
import threading
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Dict, Optional, Tuple

import numpy as np
import torch
import yaml
from jaxtyping import Float

from nerfstudio.data.dataparsers.base_dataparser import DataparserOutputs
from nerfstudio.engine.trainer import TrainerConfig
from nerfstudio.utils.eval_utils import eval_setup

from ssnerf_method.data.transforms import Transforms, frame_camera
from ssnerf_method.data.validate import transforms_file
from ssnerf_method.errors import UserError
from ssnerf_method.model.ssnerf_model import SSNeRFModel, SSNeRFModelConfig
from ssnerf_method.rendering.depth import rendered_z_depth

MIN_ACCUMULATION = 0.5
"""Pixels whose rendered opacity is below this get no depth (empty space, e.g. sky: their depth means nothing)."""
POSE_TOLERANCE = 1e-3
"""Largest gap (model units) between a training camera and its frame's moved pose; more: trained on other poses."""
COLMAP_APPLIED_TRANSFORM = [[0, 1, 0, 0], [1, 0, 0, 0], [0, 0, -1, 0]]
"""nerfstudio's `applied_transform` for a dataset without one that holds `colmap/sparse/0` (its dataparser's rule)."""


def checked_config(path: Path) -> TrainerConfig:
    """The trainer config at `path` if it is a trained SS-NeRF's (else one line why); reads no data or weights."""
    if not path.is_file():
        raise UserError(f"{path}: no such file. Pass the config.yml of a trained SS-NeRF run "
                        "(outputs/<experiment>/ssnerf-lite/<timestamp>/config.yml).")
    try:
        config = yaml.load(path.read_text(), Loader=yaml.Loader)
    except (OSError, UnicodeDecodeError, yaml.YAMLError, ImportError, AttributeError, TypeError) as err:
        raise UserError(f"{path}: not a nerfstudio config.yml ({type(err).__name__}). Pass the config.yml that "
                        "ns-train wrote for an ssnerf or ssnerf-lite run.") from err
    if not isinstance(config, TrainerConfig):
        raise UserError(f"{path}: not a nerfstudio config.yml. Pass the config.yml that ns-train wrote for an ssnerf "
                        "or ssnerf-lite run.")
    if not isinstance(config.pipeline.model, SSNeRFModelConfig):
        raise UserError(f"{path}: a {config.method_name} model, not an SS-NeRF one. Train one on the data "
                        "(ns-train ssnerf-lite --data DATA) and pass its config.yml.")
    checkpoints = config.get_checkpoint_dir()
    if not any(checkpoints.glob("step-*.ckpt")):
        raise UserError(f"{checkpoints}: holds no checkpoint (step-*.ckpt) for {path}. Point at a run that saved one "
                        "(training saves at its end), or run from the folder ns-train ran in (the paths are "
                        "relative).")
    return config


def applied_transform(meta: Dict, folder: Path) -> Tuple[Float[np.ndarray, "4 4"], float]:
    """What the dataset's file already applied to its original poses (`applied_transform`, `applied_scale`), as
    nerfstudio's dataparser reads it; the poses in the file are those original poses moved by it."""
    matrix = np.eye(4)
    if "applied_transform" in meta:
        matrix[:3] = np.asarray(meta["applied_transform"], dtype=np.float64)
    elif (folder / "colmap" / "sparse" / "0").exists():
        matrix[:3] = np.asarray(COLMAP_APPLIED_TRANSFORM, dtype=np.float64)
    return matrix, float(meta.get("applied_scale", 1.0))


def file_to_model(
    outputs: DataparserOutputs, meta: Dict, folder: Path
) -> Tuple[Float[np.ndarray, "4 4"], float]:
    """Rigid transform and scale from the transforms file's frame to the model's: `dataparser_transform` maps the
    pre-`applied_transform` frame, and `dataparser_scale` includes `applied_scale`, so both are undone."""
    transform = np.eye(4)
    transform[:3] = outputs.dataparser_transform.double().numpy()
    applied, applied_scale = applied_transform(meta, folder)
    return transform @ np.linalg.inv(applied), float(outputs.dataparser_scale) / applied_scale


def move_pose(pose: Float[np.ndarray, "4 4"], transform: Float[np.ndarray, "4 4"], scale: float) -> np.ndarray:
    """A camera-to-world of the transforms file in the model's frame (as the dataparser moved the training poses)."""
    moved = transform @ np.asarray(pose, dtype=np.float64)
    moved[:3, 3] *= scale
    return moved


@dataclass
class DepthFromModel:
    """A trained SS-NeRF that renders z-depth at a dataset's frames (one frame at a time: threads share it)."""

    config_path: Path
    model: SSNeRFModel
    step: int
    transform: np.ndarray
    """Transforms-file frame to the model's frame (rotation and translation; `scale` applies after it)."""
    scale: float
    """Model units per unit of the transforms file."""
    min_accumulation: float = MIN_ACCUMULATION

    def __post_init__(self) -> None:
        self._lock = threading.Lock()

    def render(self, transforms: Transforms, frame: Dict, resolution_scale: float) -> Dict[str, torch.Tensor]:
        """The model's outputs at the frame's pose (moved into the model's frame), at `resolution_scale`."""
        camera = frame_camera(transforms, frame)
        pose = move_pose(np.vstack([frame["transform_matrix"][:3], [0.0, 0.0, 0.0, 1.0]]), self.transform, self.scale)
        camera.camera_to_worlds = torch.from_numpy(pose[None, :3]).float()
        if resolution_scale != 1.0:
            camera.rescale_output_resolution(resolution_scale)
        with self._lock:
            return self.model.render_camera(camera.to(self.model.device))

    def z_depth(self, transforms: Transforms, frame: Dict, resolution_scale: float) -> Float[np.ndarray, "h w"]:
        """The frame's z-depth (file units) at `resolution_scale`; NaN where the render is nearly transparent."""
        return self.depth_of(self.render(transforms, frame, resolution_scale))

    def depth_of(self, outputs: Dict[str, torch.Tensor]) -> Float[np.ndarray, "h w"]:
        """z-depth (file units) of rendered `outputs`; NaN where the render is nearly transparent."""
        depth = (rendered_z_depth(outputs)[..., 0] / self.scale).double().cpu().numpy()
        opaque = outputs["accumulation"][..., 0].cpu().numpy() >= self.min_accumulation
        return np.where(opaque & np.isfinite(depth), depth, np.nan)

    def describe(self, resolution_scale: float) -> Dict:
        return {"config": str(self.config_path.resolve()), "step": self.step, "resolution_scale": resolution_scale,
                "min_accumulation": self.min_accumulation}


def load_depth_model(config_path: Path, transforms: Transforms) -> DepthFromModel:
    """Load the model at `config_path` as `ns-eval` does and check that it was trained on `transforms`' poses."""
    config = checked_config(config_path)
    _, pipeline, _, step = eval_setup(config_path, test_mode="inference")
    outputs: DataparserOutputs = pipeline.datamanager.train_dataparser_outputs  # type: ignore[attr-defined]
    data = Path(config.pipeline.datamanager.data)  # type: ignore[attr-defined]
    trained_on = transforms_file(data)
    training_meta = json.loads(trained_on.read_text())  # the dataparser has just read it
    transform, scale = file_to_model(outputs, training_meta, trained_on.parent)
    _check_same_poses(config_path, outputs, trained_on.parent, transforms, transform, scale)
    return DepthFromModel(config_path, pipeline.model, step, transform, scale)  # type: ignore[arg-type]


def _check_same_poses(
    config_path: Path, outputs: DataparserOutputs, trained_folder: Path, transforms: Transforms,
    transform: np.ndarray, scale: float,
) -> None:
    """The model's training cameras sit where the dataset's frames of the same images land in the model's frame."""
    cameras = outputs.cameras.camera_to_worlds.double().numpy()
    by_name: Dict[PurePosixPath, Optional[np.ndarray]] = {}
    for path, pose in zip(outputs.image_filenames, cameras):
        relative = relative_image_path(Path(path), trained_folder)
        by_name[relative] = None if relative in by_name else pose  # an image listed twice: not compared
    matched = 0
    for frame in transforms.frames:
        pose = by_name.get(PurePosixPath(*[p for p in PurePosixPath(frame["file_path"]).parts if p != "."]))
        if pose is None:
            continue
        matched += 1
        moved = move_pose(np.vstack([frame["transform_matrix"][:3], [0.0, 0.0, 0.0, 1.0]]), transform, scale)
        if np.abs(moved[:3] - pose).max() > POSE_TOLERANCE:
            raise UserError(
                f"{config_path}: trained on {trained_folder}, where frame {frame['file_path']} has another pose than "
                f"in {transforms.path}. Train a model on this dataset (ns-train ssnerf-lite --data "
                f"{transforms.folder}) and pass its config.yml."
            )
    if matched == 0:
        raise UserError(
            f"{config_path}: trained on {trained_folder}, which has none of the images of {transforms.path}. Train a "
            f"model on this dataset (ns-train ssnerf-lite --data {transforms.folder}) and pass its config.yml."
        )


def relative_image_path(path: Path, folder: Path) -> PurePosixPath:
    """An image path of the dataparser relative to its dataset folder (its downscaled `images_N` folder as `images`)."""
    try:
        parts = list(path.resolve().relative_to(folder.resolve()).parts)
    except ValueError:
        parts = list(path.parts[-2:])
    if parts and parts[0].startswith("images_") and parts[0][len("images_"):].isdigit():
        parts[0] = "images"
    return PurePosixPath(*parts)
