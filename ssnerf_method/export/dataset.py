"""`ssnerf-export-dataset`: a trained model's renders as a new dataset in the SS-NeRF format (the paper's
auto-labeller / data creation use, and the rendered data of its data-augmentation study).

For each pose it writes the rendered RGB and every property the model has, encoded as the dataset format stores
labels (`PropertyKind.encode`: class ids, (n+1)/2 normals, value/255 maps), plus the rendered z-depth in millimetres.
The poses are those of a split of the model's dataset, and/or new ones between adjacent poses of that split (the
paper's novel poses: the average of two adjacent training poses is `--between 1`). The output trains with
`ns-train ssnerf-lite --data OUT` like any other dataset: its poses are written in the source dataset's frame, so
renders and ground truth of the same scene line up.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Dict, List, Literal

import numpy as np
import torch
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from nerfstudio.cameras.cameras import Cameras
from nerfstudio.utils.eval_utils import eval_setup
from nerfstudio.utils.rich_utils import CONSOLE

from ssnerf_method.data.camera_path import interpolate_poses
from ssnerf_method.data.io import DatasetInputError, StagedOutputFolder
from ssnerf_method.importers.writer import DatasetWriter
from ssnerf_method.rendering.depth import rendered_z_depth

DEPTH_UNIT = 1e-3
"""Metres per unit of the written depth maps (nerfstudio's default `depth_unit_scale_factor`)."""


@dataclass
class ExportDatasetConfig:
    """Render RGB and every property of a trained SS-NeRF at a split's poses (and between them) into a new dataset."""

    load_config: Path
    """config.yml of the trained model (as for `ns-eval`)."""
    output_dir: Path
    """Folder of the new dataset (must be missing or empty unless --overwrite)."""
    split: Literal["train", "test"] = "train"
    """Whose poses: the model's training views or its test views."""
    between: int = 0
    """New poses inserted between each two adjacent poses of the split (evenly spaced; 1 = the midpoint)."""
    include_split_poses: bool = True
    """Also render at the split's own poses (with --between, False keeps only the new poses)."""
    depth: bool = True
    """Write the rendered z-depth (`depth/`, uint16 millimetres)."""
    test_every: int = 8
    """In the new dataset, frame i is a test (and val) frame when i % test_every == test_every // 2; 0: none."""
    overwrite: bool = False
    """Replace a non-empty output folder."""


@dataclass
class ExportPose:
    """One pose to render: which camera's intrinsics, which camera-to-world (model frame), where it came from."""

    camera_index: int
    camera_to_world: np.ndarray
    source: Dict[str, Any]


def export_poses(cameras: Cameras, names: List[str], config: ExportDatasetConfig) -> List[ExportPose]:
    """The split's poses in order, with `between` new poses after each (but the last)."""
    if not config.include_split_poses and config.between < 1:
        raise DatasetInputError("--no-include-split-poses leaves nothing to render without --between N (N >= 1).")
    fractions = [(k + 1) / (config.between + 1) for k in range(config.between)]
    c2w = cameras.camera_to_worlds.cpu().numpy().astype(np.float64)
    poses: List[ExportPose] = []
    for index in range(len(names)):
        if config.include_split_poses:
            poses.append(ExportPose(index, c2w[index], {"pose_of": names[index]}))
        if index + 1 < len(names) and fractions:
            for fraction, pose in zip(fractions, interpolate_poses(c2w[index], c2w[index + 1], fractions)):
                source = {"between": [names[index], names[index + 1]], "fraction": round(fraction, 6)}
                poses.append(ExportPose(index, pose, source))
    return poses


def camera_at(cameras: Cameras, pose: ExportPose) -> Cameras:
    """Camera `pose.camera_index` of `cameras` (its intrinsics and distortion) moved to `pose.camera_to_world`."""
    camera = cameras[pose.camera_index : pose.camera_index + 1]
    camera.camera_to_worlds = torch.from_numpy(pose.camera_to_world[None]).to(camera.camera_to_worlds)
    return camera


def intrinsics_of(cameras: Cameras, index: int) -> Dict[str, Any]:
    """transforms.json intrinsics of one camera (nerfstudio's OPENCV model and distortion order)."""
    k1, k2, k3, k4, p1, p2 = (float(value) for value in cameras.distortion_params[index].tolist()) \
        if cameras.distortion_params is not None else (0.0,) * 6
    return {
        "camera_model": "OPENCV", "fl_x": float(cameras.fx[index]), "fl_y": float(cameras.fy[index]),
        "cx": float(cameras.cx[index]), "cy": float(cameras.cy[index]), "w": int(cameras.width[index]),
        "h": int(cameras.height[index]), "k1": k1, "k2": k2, "k3": k3, "k4": k4, "p1": p1, "p2": p2,
    }  # fmt: skip


def export_dataset(config: ExportDatasetConfig) -> Path:
    """Render and write the dataset; returns its transforms.json. Nothing is left behind if it fails."""
    if not config.load_config.is_file():
        raise DatasetInputError(f"{config.load_config}: no such config.yml. Pass the config.yml of a trained model "
                                "(outputs/<experiment>/<method>/<timestamp>/config.yml).")
    _, pipeline, _, step = eval_setup(config.load_config, test_mode="test")
    model = pipeline.model
    datamanager = pipeline.datamanager
    dataset = datamanager.train_dataset if config.split == "train" else datamanager.eval_dataset  # type: ignore
    cameras: Cameras = dataset.cameras
    names = [Path(name).name for name in dataset.image_filenames]
    poses = export_poses(cameras, names, config)
    parser_outputs = datamanager.train_dataparser_outputs  # type: ignore[attr-defined]
    specs = [spec for spec in model.specs if spec.file_key is not None]  # type: ignore[attr-defined]
    shared = intrinsics_of(cameras, 0)

    with StagedOutputFolder(config.output_dir, config.overwrite) as folder:
        writer = DatasetWriter(folder)
        columns = (TextColumn("[progress.description]{task.description}"), BarColumn(), MofNCompleteColumn(),
                   TimeElapsedColumn())
        with Progress(*columns, console=CONSOLE) as progress:
            task = progress.add_task(f"Rendering {len(poses)} views", total=len(poses))
            for number, pose in enumerate(poses):
                outputs = model.render_camera(camera_at(cameras, pose).to(model.device))  # type: ignore
                labels = {spec.name: spec.kind.encode(outputs[spec.prediction_key]) for spec in specs}
                if config.depth:
                    z_depth = rendered_z_depth(outputs) / parser_outputs.dataparser_scale
                    labels["depth"] = depth_millimetres(z_depth[..., 0])
                c2w = parser_outputs.transform_poses_to_original_space(
                    torch.from_numpy(pose.camera_to_world[None]).float(), camera_convention="opengl"
                )[0].numpy()
                rgb = model.rgb_spec.kind.encode(outputs[model.rgb_spec.prediction_key])  # type: ignore
                writer.add_frame(number, rgb, np.vstack([c2w, [0.0, 0.0, 0.0, 1.0]]), labels)
                frame = writer.frames[-1]
                frame["ssnerf_source"] = pose.source
                per_camera = intrinsics_of(cameras, pose.camera_index)
                frame.update({key: value for key, value in per_camera.items() if value != shared[key]})
                progress.advance(task)
        files = [frame["file_path"] for frame in writer.frames]
        held_out = [name for i, name in enumerate(files) if config.test_every and
                    i % config.test_every == config.test_every // 2]
        splits = {"train": [name for name in files if name not in held_out], "val": held_out, "test": held_out}
        # the named classes only (a model's spare class slots without a name are never predicted)
        palette = (model.palette[: len(model.class_names)] * 255).round().int().tolist()  # type: ignore
        provenance = {
            "tool": "ssnerf-export-dataset", "model_config": str(config.load_config.resolve()), "step": step,
            "split": config.split, "between": config.between, "include_split_poses": config.include_split_poses,
            "labels": "rendered by the model: RGB, " + ", ".join(spec.name for spec in specs)
            + (", z-depth (millimetres)" if config.depth else ""),
        }
        writer.write_transforms(
            shared, splits, provenance,
            semantic_classes=list(model.class_names) if model.num_classes else None,  # type: ignore
            semantic_colors=[tuple(colour) for colour in palette] if model.num_classes else None,  # type: ignore
            provenance_key="ssnerf_export",
        )
    return config.output_dir / "transforms.json"


def depth_millimetres(z_depth: torch.Tensor) -> np.ndarray:
    """(H, W) z-depth in metres as uint16 in units of `DEPTH_UNIT` (0 = no depth, beyond 65.535 m clipped)."""
    values = torch.nan_to_num(z_depth.detach().float(), nan=0.0).cpu().numpy() / DEPTH_UNIT
    return np.clip(np.round(values), 0, 65535).astype(np.uint16)
