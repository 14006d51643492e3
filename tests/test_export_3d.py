"""3D out of a trained SS-NeRF: nerfstudio's own `ns-export` (point cloud with world normals or class colours, Poisson
and TSDF meshes) and our labelled point cloud, checked against the model's renders of the views the points came from."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Dict, Tuple

import numpy as np
import pytest
import torch
from plyfile import PlyData
from scipy.spatial import cKDTree

from nerfstudio.scripts.exporter import ExportPointCloud, ExportPoissonMesh, ExportTSDFMesh
from nerfstudio.utils.eval_utils import eval_setup

from ssnerf_method.cli.export_points import ExportPointsConfig
from ssnerf_method.cli.export_points import main as export_points


@pytest.fixture(scope="module")
def renders(trained_scene) -> Tuple[object, Dict[str, np.ndarray]]:
    """The trained pipeline, and every training view rendered: world points, world normals (the camera-frame
    `normals` output rotated here by each camera's own rotation), class ids; one row per pixel."""
    torch.set_num_threads(1)
    _, config_path = trained_scene
    _, pipeline, _, _ = eval_setup(config_path)
    cameras = pipeline.datamanager.train_dataset.cameras
    points, normals, classes = [], [], []
    for index in range(len(cameras)):
        camera = cameras[index : index + 1]
        outputs = pipeline.model.render_camera(camera)
        rays = camera.generate_rays(camera_indices=0, keep_shape=True)
        points.append((rays.origins + rays.directions * outputs["depth"]).reshape(-1, 3))
        rotation = camera.camera_to_worlds[0, :3, :3]
        camera_frame = outputs["normals"].reshape(-1, 3) * 2.0 - 1.0
        normals.append(torch.nn.functional.normalize(camera_frame @ rotation.T, dim=-1))
        classes.append(outputs["semantics_logits"].argmax(-1).numpy())
    return pipeline, {"points": torch.cat(points).numpy(), "normals": torch.cat(normals).numpy(), "classes": classes}


def read_vertices(path: Path) -> np.ndarray:
    return PlyData.read(str(path))["vertex"].data


def nearest(rendered: np.ndarray, exported: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    distances, indices = cKDTree(rendered).query(exported)
    return distances, indices


def test_ns_export_pointcloud_with_world_normals(trained_scene, renders, tmp_path: Path) -> None:
    _, config_path = trained_scene
    ExportPointCloud(load_config=config_path, output_dir=tmp_path, num_points=3000, remove_outliers=False,
                     normal_output_name="normals_world", num_rays_per_batch=1024, reorient_normals=False).main()
    vertices = read_vertices(tmp_path / "point_cloud.ply")
    exported = np.stack([vertices[axis] for axis in "xyz"], -1)
    normals = np.stack([vertices[name] for name in ("nx", "ny", "nz")], -1)
    assert len(exported) >= 2000
    np.testing.assert_allclose(np.linalg.norm(normals, axis=-1), 1.0, atol=1e-3)
    _, data = renders
    distances, indices = nearest(data["points"], exported)
    assert np.median(distances) < 1e-3  # the export's points are the rendered pixels' points
    agreement = np.einsum("ij,ij->i", normals, data["normals"][indices])  # (not re-oriented to face the camera)
    assert np.mean(agreement > 0.99) > 0.95, np.percentile(agreement, [5, 50])


def test_ns_export_pointcloud_in_class_colours(trained_scene, renders, tmp_path: Path) -> None:
    _, config_path = trained_scene
    ExportPointCloud(load_config=config_path, output_dir=tmp_path, num_points=2000, remove_outliers=False,
                     normal_output_name="normals_world", rgb_output_name="semantics", num_rays_per_batch=1024).main()
    vertices = read_vertices(tmp_path / "point_cloud.ply")
    colours = np.stack([vertices[name] for name in ("red", "green", "blue")], -1).astype(int)
    pipeline, _ = renders
    palette = np.round(pipeline.model.palette.numpy() * 255).astype(int)
    distance = np.abs(colours[:, None, :] - palette[None]).max(-1).min(-1)
    assert (distance <= 1).all()  # every point is painted in a class colour
    assert len(np.unique(colours, axis=0)) >= 3


def test_ns_export_meshes(trained_scene, tmp_path: Path) -> None:
    """Poisson (from the world normals) and TSDF (semantics as the colour) run and write a non-empty mesh. (Their
    default "nerf" texturing unwraps the mesh in a Python loop: minutes on a CPU, so the vertex colours are used.)"""
    import open3d as o3d

    _, config_path = trained_scene
    ExportPoissonMesh(load_config=config_path, output_dir=tmp_path / "poisson", num_points=3000,
                      remove_outliers=False, normal_output_name="normals_world", num_rays_per_batch=1024,
                      save_point_cloud=False, texture_method="point_cloud").main()
    ExportTSDFMesh(load_config=config_path, output_dir=tmp_path / "tsdf", resolution=32, rgb_output_name="semantics",
                   batch_size=2, texture_method="tsdf").main()
    for path in (tmp_path / "poisson" / "poisson_mesh.ply", tmp_path / "tsdf" / "tsdf_mesh.ply"):
        mesh = o3d.io.read_triangle_mesh(str(path))
        assert len(mesh.vertices) > 0 and len(mesh.triangles) > 0, path


def test_labelled_point_cloud_round_trip(trained_scene, renders, tmp_path: Path) -> None:
    _, config_path = trained_scene
    arrays = export_points(ExportPointsConfig(load_config=config_path, output_dir=tmp_path, num_points=3000,
                                              remove_outliers=False, num_rays_per_batch=1024, split_by_class=True))
    ply = PlyData.read(str(tmp_path / "points.ply"))
    vertices = ply["vertex"].data
    names = set(vertices.dtype.names)
    assert {"x", "y", "z", "red", "green", "blue", "nx", "ny", "nz", "semantics", "semantics_uncertainty", "shading",
            "keypoints", "edges", "view", "row", "col"} <= names
    assert len(vertices) == len(arrays["x"]) == 3000
    classes = json.loads((tmp_path / "classes.json").read_text())
    assert [comment for comment in ply.comments if comment.startswith("class 0 ")] == [f"class 0 {classes['names'][0]}"]
    normals = np.stack([vertices[name] for name in ("nx", "ny", "nz")], -1)
    np.testing.assert_allclose(np.linalg.norm(normals, axis=-1), 1.0, atol=1e-3)
    for name in ("semantics_uncertainty", "shading", "keypoints", "edges"):
        assert vertices[name].dtype == np.float32 and 0.0 <= vertices[name].min() <= vertices[name].max() <= 1.0

    _, data = renders
    rendered = np.array([data["classes"][view][row, col] for view, row, col in
                         zip(vertices["view"], vertices["row"], vertices["col"])])
    assert np.mean(rendered == vertices["semantics"]) > 0.99  # each point's class is its pixel's rendered class
    assert len(np.unique(vertices["semantics"])) >= 3
    split = sorted(tmp_path.glob("points_*.ply"))
    assert sum(len(read_vertices(path)) for path in split) == len(vertices)
    assert all(len(np.unique(read_vertices(path)["semantics"])) == 1 for path in split)
