"""`ssnerf-export-dataset`: a trained model's renders written as a dataset of this plugin's format that reads back as
the renders, lines up with the source poses, trains, and never half-writes; and the pose interpolation."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from nerfstudio.utils.eval_utils import eval_setup

from ssnerf_method.data.camera_path import interpolate_poses
from ssnerf_method.data.dataparser import SSNeRFDataParserConfig
from ssnerf_method.data.dataset import DEPTH_KEY, SSNeRFDataset
from ssnerf_method.data.io import DatasetInputError
from ssnerf_method.export.dataset import ExportDatasetConfig, export_dataset
from ssnerf_method.properties import OPTIONAL_PROPERTIES, REGISTRY


def test_interpolated_poses_are_proper_rotations_between_the_ends() -> None:
    first = np.hstack([Rotation.from_euler("xyz", [0.1, 0.2, 0.3]).as_matrix(), [[0.0], [1.0], [2.0]]])
    second = np.hstack([Rotation.from_euler("xyz", [0.5, -0.4, 1.0]).as_matrix(), [[2.0], [1.0], [0.0]]])
    poses = interpolate_poses(first, second, [0.0, 0.25, 0.5, 1.0])
    for pose in poses:
        rotation = pose[:, :3]
        assert np.allclose(rotation.T @ rotation, np.eye(3), atol=1e-9) and np.isclose(np.linalg.det(rotation), 1.0)
    assert np.allclose(poses[0], first) and np.allclose(poses[-1], second)
    assert np.allclose(poses[2][:, 3], [1.0, 1.0, 1.0])  # the midpoint's centre is the average
    # the midpoint's rotation is half way: equal angles to both ends
    to_first = Rotation.from_matrix(poses[2][:, :3].T @ first[:, :3]).magnitude()
    to_second = Rotation.from_matrix(poses[2][:, :3].T @ second[:, :3]).magnitude()
    assert to_first == pytest.approx(to_second) and to_first > 0.1


def test_export_reads_back_as_the_renders_at_the_training_poses(trained_scene, tmp_path: Path) -> None:
    scene, config = trained_scene
    output = tmp_path / "rendered"
    export_dataset(ExportDatasetConfig(load_config=config, output_dir=output, between=1, test_every=4))
    meta = json.loads((output / "transforms.json").read_text())
    source = json.loads((scene / "transforms.json").read_text())
    train_names = sorted(Path(name).name for name in source["train_filenames"])
    assert len(meta["frames"]) == 2 * len(train_names) - 1  # each training pose, and one between each neighbour pair
    assert meta["semantic_classes"] == source["semantic_classes"]
    assert meta["ssnerf_export"]["between"] == 1
    first = meta["frames"][0]
    assert first["ssnerf_source"] == {"pose_of": train_names[0]}
    assert meta["frames"][1]["ssnerf_source"]["between"] == train_names[:2]
    # poses are written in the source dataset's frame: frame 0 sits where the first training frame does
    original = next(frame for frame in source["frames"] if Path(frame["file_path"]).name == train_names[0])
    assert np.allclose(first["transform_matrix"], original["transform_matrix"], atol=1e-5)
    for key in [*(REGISTRY[name].file_key for name in OPTIONAL_PROPERTIES), "depth_file_path"]:
        assert (output / first[key]).is_file(), key

    # it is a dataset of this plugin's format: it loads, and its labels are the model's renders at those poses
    parser = SSNeRFDataParserConfig(data=output).setup()
    exported = SSNeRFDataset(parser.get_dataparser_outputs("train"))
    assert set(exported.metadata["available_properties"]) == set(OPTIONAL_PROPERTIES)
    _, pipeline, _, _ = eval_setup(config, test_mode="test")
    model = pipeline.model
    outputs = model.render_camera(pipeline.datamanager.train_dataset.cameras[0:1])
    item = exported[0]
    assert torch.allclose(item["image"][..., :3], outputs["rgb"], atol=1.0 / 255)
    assert torch.equal(item["semantics"][..., 0].long(), outputs["semantics_logits"].argmax(-1))
    assert torch.allclose(item["normals"], outputs["normals"], atol=0.5 / 255 + 1e-6)
    assert torch.allclose(item["edges"], outputs["edges_value"].clamp(0, 1), atol=0.5 / 255 + 1e-6)
    z_depth = (outputs["depth"] / outputs["directions_norm"])[..., 0] / model.dataparser_scale
    assert torch.allclose(item[DEPTH_KEY][..., 0], z_depth, atol=1e-3)


def test_bad_input_leaves_nothing_behind(trained_scene, tmp_path: Path) -> None:
    _, config = trained_scene
    with pytest.raises(DatasetInputError, match="config.yml"):
        export_dataset(ExportDatasetConfig(load_config=tmp_path / "missing.yml", output_dir=tmp_path / "out"))
    occupied = tmp_path / "occupied"
    occupied.mkdir()
    (occupied / "keep.txt").write_text("user data")
    with pytest.raises(DatasetInputError, match="--overwrite"):
        export_dataset(ExportDatasetConfig(load_config=config, output_dir=occupied))
    with pytest.raises(DatasetInputError, match="--between"):
        export_dataset(ExportDatasetConfig(load_config=config, output_dir=tmp_path / "none",
                                           include_split_poses=False))
    assert (occupied / "keep.txt").read_text() == "user data"
    assert sorted(path.name for path in tmp_path.iterdir()) == ["occupied"]
