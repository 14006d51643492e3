"""`ssnerf-export-points`: a labelled point cloud of a trained SS-NeRF: geometry and semantics in one PLY, for robots.

Points are sampled as `ns-export pointcloud` samples them: batches of training rays from the datamanager, each point
at its ray's rendered depth, kept where the accumulation is above 0.5 and inside the optional oriented box, then
cleaned of statistical outliers with Open3D (nerfstudio's `std_ratio`). Each vertex carries, from the registry's kinds,
every trained property: `red green blue` (RGB), `nx ny nz` (the world-frame unit normal), the semantic class id and
its uncertainty (`semantics_uncertainty`, 0 to 1: drop points above a threshold for cleaner labels), one float per
scalar map (shading, keypoints, edges), and where it came from (`view`, `row`, `col`: the training image and
pixel), so that any value can be checked against that view's render. The class names and colours are in the PLY's
header comments and in `classes.json`; `--split-by-class` also writes one PLY per class present.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional, Tuple

import numpy as np
import torch
import tyro
from plyfile import PlyData, PlyElement

from nerfstudio.cameras.rays import RayBundle
from nerfstudio.data.scene_box import OrientedBox
from nerfstudio.pipelines.base_pipeline import Pipeline
from nerfstudio.utils.eval_utils import eval_setup
from nerfstudio.utils.rich_utils import CONSOLE, get_progress

from ssnerf_method.atomic import atomic_file, write_text_atomic
from ssnerf_method.errors import UserError, exit_with
from ssnerf_method.model.ssnerf_model import SSNeRFModel

PLY_NAME = "points.ply"
SOURCE_FIELDS = ("view", "row", "col")
"""Per-point provenance: training image index (the datamanager's), pixel row and column."""


@dataclass
class ExportPointsConfig:
    """Write a labelled point cloud (PLY) of a trained SS-NeRF: position, colour, world normal, class id and every
    scalar property per point, sampled as `ns-export pointcloud` samples."""

    load_config: Path
    """The trained model's config.yml (as for ns-export)."""
    output_dir: Path
    """Folder for points.ply, classes.json (and the per-class PLYs)."""
    num_points: int = 1000000
    """Points to sample (fewer remain after outlier removal), as ns-export."""
    remove_outliers: bool = True
    """Drop statistical outliers (Open3D, 20 neighbours), as ns-export."""
    std_ratio: float = 10.0
    """Outlier threshold on the standard deviation of neighbour distances, as ns-export."""
    obb_center: Optional[Tuple[float, float, float]] = None
    """Centre of an oriented box to crop to (with --obb-rotation and --obb-scale), as ns-export."""
    obb_rotation: Optional[Tuple[float, float, float]] = None
    """Rotation of the box, roll-pitch-yaw in radians."""
    obb_scale: Optional[Tuple[float, float, float]] = None
    """Size of the box along each of its axes."""
    num_rays_per_batch: int = 32768
    """Rays rendered per batch (lower it if memory runs out)."""
    save_world_frame: bool = False
    """Positions and normals in the dataset's original frame instead of the model's (nerfstudio's scaled, centred
    frame), as ns-export."""
    split_by_class: bool = False
    """Also write points_<id>_<class>.ply per class present."""


def sample_points(pipeline: Pipeline, config: ExportPointsConfig) -> Dict[str, np.ndarray]:
    """Per-point arrays (PLY property name -> (N,) values) sampled from training rays until `num_points`."""
    model = pipeline.model
    assert isinstance(model, SSNeRFModel)
    datamanager = pipeline.datamanager
    datamanager.train_pixel_sampler.num_rays_per_batch = config.num_rays_per_batch  # type: ignore[union-attr]
    box = None
    if config.obb_center is not None and config.obb_rotation is not None and config.obb_scale is not None:
        box = OrientedBox.from_params(config.obb_center, config.obb_rotation, config.obb_scale)
    columns: Dict[str, List[torch.Tensor]] = {}
    count = 0
    progress = get_progress("Sampling labelled points", suffix="points")
    with progress:
        task = progress.add_task("points", total=config.num_points)
        while count < config.num_points:
            with torch.no_grad():
                ray_bundle, batch = datamanager.next_train(0)  # type: ignore[attr-defined]
                assert isinstance(ray_bundle, RayBundle)
                outputs = model(ray_bundle)
            points = ray_bundle.origins + ray_bundle.directions * outputs["depth"]
            keep = outputs["accumulation"][..., 0] > 0.5
            if box is not None:
                keep &= box.within(points)
            values = {"x": points[..., 0], "y": points[..., 1], "z": points[..., 2]}
            for spec in model.specs:
                values.update(spec.kind.point_values(spec.name, outputs))
            indices = batch["indices"].to(points.device)
            values.update(dict(zip(SOURCE_FIELDS, indices.int().unbind(-1))))
            for name, value in values.items():
                columns.setdefault(name, []).append(value[keep].cpu())
            count += int(keep.sum())
            progress.update(task, completed=min(count, config.num_points))
    arrays = {name: torch.cat(parts)[: config.num_points].numpy() for name, parts in columns.items()}
    if config.remove_outliers and len(arrays["x"]) > 20:
        import open3d as o3d

        cloud = o3d.geometry.PointCloud()
        cloud.points = o3d.utility.Vector3dVector(np.stack([arrays[axis] for axis in "xyz"], -1).astype(np.float64))
        _, kept = cloud.remove_statistical_outlier(nb_neighbors=20, std_ratio=config.std_ratio)
        arrays = {name: values[np.asarray(kept)] for name, values in arrays.items()}
    if config.save_world_frame:
        arrays = to_original_frame(pipeline, arrays)
    return arrays


def to_original_frame(pipeline: Pipeline, arrays: Dict[str, np.ndarray]) -> Dict[str, np.ndarray]:
    """Positions and normals moved back through the dataparser's transform (nerfstudio's `--save-world-frame`)."""
    count = len(arrays["x"])
    poses = torch.eye(4)[None, :3].repeat(count, 1, 1)
    poses[:, :3, 3] = torch.from_numpy(np.stack([arrays[axis] for axis in "xyz"], -1)).float()
    moved = pipeline.datamanager.train_dataparser_outputs.transform_poses_to_original_space(poses)  # type: ignore
    result = dict(arrays)
    for axis, values in zip("xyz", moved[:, :3, 3].numpy().T):
        result[axis] = values
    if "nx" in arrays:
        normals = torch.from_numpy(np.stack([arrays[name] for name in ("nx", "ny", "nz")], -1)).float()
        rotated = torch.nn.functional.normalize(torch.einsum("nij,nj->ni", moved[:, :3, :3], normals), dim=-1)
        for name, values in zip(("nx", "ny", "nz"), rotated.numpy().T):
            result[name] = values
    return result


def write_ply(path: Path, arrays: Dict[str, np.ndarray], comments: List[str]) -> None:
    """A binary PLY with one `vertex` element holding every array as a property (positions first), whole or not at
    all (`atomic.atomic_file`)."""
    order = ["x", "y", "z", *[name for name in arrays if name not in "xyz"]]
    vertices = np.empty(len(arrays["x"]), dtype=[(name, arrays[name].dtype.str) for name in order])
    for name in order:
        vertices[name] = arrays[name]
    with atomic_file(path, "wb") as stream:
        PlyData([PlyElement.describe(vertices, "vertex")], comments=comments).write(stream)


def main(config: ExportPointsConfig) -> Dict[str, np.ndarray]:
    start = time.perf_counter()
    _, pipeline, _, _ = eval_setup(config.load_config)
    model = pipeline.model
    if not isinstance(model, SSNeRFModel):
        raise UserError(f"{config.load_config}: not an SS-NeRF model. Use ns-export for other methods.")
    arrays = sample_points(pipeline, config)
    names = list(model.class_names) if model.class_spec is not None else []
    colours = (model.palette * 255).round().int().tolist() if names else []
    frame = "original dataset" if config.save_world_frame else "nerfstudio model"
    comments = ["ssnerf-export-points", f"frame {frame}"]
    comments += [f"class {index} {name}" for index, name in enumerate(names)]
    config.output_dir.mkdir(parents=True, exist_ok=True)
    write_ply(config.output_dir / PLY_NAME, arrays, comments)
    classes = json.dumps({"names": names, "colors": colours}, indent=2) + "\n"
    write_text_atomic(config.output_dir / "classes.json", classes)
    class_field = None if model.class_spec is None else model.class_spec.name
    if config.split_by_class and class_field is not None:
        for index in np.unique(arrays[class_field]):
            mask = arrays[class_field] == index
            name = names[index] if index < len(names) else str(index)
            write_ply(config.output_dir / f"points_{index:02d}_{name}.ply",
                      {key: values[mask] for key, values in arrays.items()}, comments)
    size = (config.output_dir / PLY_NAME).stat().st_size
    CONSOLE.print(f"Wrote {len(arrays['x'])} points ({', '.join(name for name in arrays if name not in 'xyz')}) to "
                  f"{config.output_dir / PLY_NAME} ({size / 1e6:.1f} MB) in {time.perf_counter() - start:.1f} s.",
                  soft_wrap=True, highlight=False)
    return arrays


def entrypoint() -> None:
    """Console script."""
    config = tyro.cli(ExportPointsConfig)
    try:
        main(config)
    except UserError as error:
        exit_with(error, "ssnerf-export-points")


if __name__ == "__main__":
    entrypoint()
