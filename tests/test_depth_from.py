"""`ssnerf-label --depth-from CONFIG`: frames without depth get normals and shading from a trained model's rendered
z-depth. The frame poses reach the model's frame exactly as nerfstudio's dataparser moves them (its `applied_transform`
and scale included); with the shared briefly trained model every frame gets normals and shading; with a ray caster
standing in for the model (the 150-step model's depth is too rough to judge) the normals match those from the true
depth far better than a constant depth's; a bad CONFIG is one line and nothing is written."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Callable, Dict, List

import numpy as np
import pytest
import torch
import yaml
from PIL import Image

from nerfstudio.data.dataparsers.base_dataparser import transform_poses_to_original_space

from ssnerf_method.cli.label import main as label_main
from ssnerf_method.data.dataparser import SSNeRFDataParserConfig
from ssnerf_method.data.transforms import load_transforms
from ssnerf_method.label_tool.label_dataset import LABELLED, LabelDatasetConfig, label_dataset
from ssnerf_method.label_tool.rendered_depth import file_to_model, load_depth_model, move_pose
from ssnerf_method.model.ssnerf_model import SSNeRFModel
from ssnerf_method.rendering.depth import rendered_z_depth
from ssnerf_method.scene.raycast import PinholeCamera, cast_rays, pixel_grid
from ssnerf_method.scene.room import build_room

from conftest import ssnerf_label_refuses

DEPTH_KEYS = ("depth_file_path", "normals_file_path", "shading_file_path")
ONLY_NORMALS = dict(edges=False, keypoints=False, semantics=False, workers=1)


def without_depth(scene: Path, target: Path) -> Path:
    """A copy of the scene whose frames list no depth, normals or shading (a capture without a depth sensor)."""
    shutil.copytree(scene, target)
    meta = json.loads((target / "transforms.json").read_text())
    for frame in meta["frames"]:
        for key in DEPTH_KEYS:
            frame.pop(key)
    (target / "transforms.json").write_text(json.dumps(meta))
    return target


def normals(path: Path) -> np.ndarray:
    encoded = np.asarray(Image.open(path))
    decoded = encoded[..., :3] / 255.0 * 2.0 - 1.0
    decoded /= np.linalg.norm(decoded, axis=-1, keepdims=True)
    if encoded.shape[-1] == 4:
        decoded[encoded[..., 3] == 0] = np.nan
    return decoded


def median_angle(first: List[np.ndarray], second: List[np.ndarray]) -> float:
    angles = [np.degrees(np.arccos(np.clip(np.einsum("hwc,hwc->hw", a, b), -1, 1))) for a, b in zip(first, second)]
    values = np.concatenate([angle[np.isfinite(angle)] for angle in angles])
    return float(np.median(values))


def test_poses_reach_the_model_frame_as_the_dataparser_moves_them(tmp_path: Path) -> None:
    """An ns-process-data capture lists `applied_transform` (and here `applied_scale`): the dataparser's training
    cameras are the file's poses moved by `file_to_model`."""
    from test_label_dataset import write_capture

    data = write_capture(tmp_path / "capture")
    meta = json.loads((data / "transforms.json").read_text())
    meta["applied_scale"] = 0.5
    (data / "transforms.json").write_text(json.dumps(meta))
    outputs = SSNeRFDataParserConfig(data=data).setup().get_dataparser_outputs("train")
    transform, scale = file_to_model(outputs, meta, data)
    moved = [move_pose(np.vstack([frame["transform_matrix"][:3], [0, 0, 0, 1]]), transform, scale)[:3]
             for frame in meta["frames"]]
    names = [Path(frame["file_path"]).name for frame in meta["frames"]]
    cameras = outputs.cameras.camera_to_worlds.double().numpy()
    for path, camera in zip(outputs.image_filenames, cameras):
        np.testing.assert_allclose(moved[names.index(Path(path).name)], camera, atol=1e-5)
    assert not np.allclose(transform, outputs.dataparser_transform.numpy().tolist() + [[0, 0, 0, 1]], atol=1e-3)


def test_depth_from_labels_every_frame_with_the_models_depth(trained_scene, tmp_path: Path) -> None:
    scene, config_path = trained_scene
    data = without_depth(scene, tmp_path / "data")
    report = label_main(LabelDatasetConfig(data=data, depth_from=config_path, **ONLY_NORMALS))
    assert report.outcomes["normals"] == {LABELLED: 10} and report.outcomes["shading"] == {LABELLED: 10}
    meta = json.loads((data / "transforms.json").read_text())
    record = meta["ssnerf_label"]["depth_from"]
    assert record["config"] == str(config_path.resolve())
    assert record["resolution_scale"] == LabelDatasetConfig(data=data).depth_from_scale
    assert record["smoothing"] == LabelDatasetConfig(data=data).depth_from_smoothing > 0
    assert record["frames"] == [frame["file_path"] for frame in meta["frames"]]
    assert all("depth_file_path" not in frame for frame in meta["frames"])  # nothing claims sensor depth

    # The depth is the model's own render at its training cameras (the dataparser's), at half resolution.
    transforms = load_transforms(data)
    model = load_depth_model(config_path, transforms)
    outputs = SSNeRFDataParserConfig(data=scene).setup().get_dataparser_outputs("train")
    names = [Path(path).name for path in outputs.image_filenames]
    for frame in transforms.frames[:3]:
        if Path(frame["file_path"]).name not in names:
            continue
        index = names.index(Path(frame["file_path"]).name)
        camera = outputs.cameras[index : index + 1]
        camera.rescale_output_resolution(0.5)
        expected = rendered_z_depth(model.model.render_camera(camera))[..., 0] / outputs.dataparser_scale
        np.testing.assert_allclose(model.z_depth(transforms, frame, 0.5), expected.double().numpy(), rtol=1e-4)
        assert Image.open(data / frame["normals_file_path"]).size == (40, 30)  # mapped back to the image's pixels


@pytest.fixture
def ray_caster_as_model(trained_scene, monkeypatch) -> None:
    """The model's render replaced by the generated room's exact z-depth at the camera it is given (moved back to
    the scene's frame by nerfstudio's own inverse of the dataparser transform)."""
    scene, _ = trained_scene
    outputs = SSNeRFDataParserConfig(data=scene).setup().get_dataparser_outputs("train")
    room = build_room(0)

    def render(self, camera, obb_box=None) -> Dict[str, torch.Tensor]:
        pose = transform_poses_to_original_space(camera.camera_to_worlds.cpu().double(),
                                                 outputs.dataparser_transform.double(), outputs.dataparser_scale,
                                                 camera_convention="opengl")[0].numpy()
        width, height = int(camera.width), int(camera.height)
        caster = PinholeCamera(width, height, float(camera.fx), float(camera.fy), float(camera.cx),
                               float(camera.cy), np.vstack([pose, [0, 0, 0, 1]]))
        origin, directions = caster.rays(*(grid.reshape(-1) for grid in pixel_grid(width, height)))
        depth = cast_rays(room.primitives, origin, directions).t.reshape(height, width, 1)
        hit = np.isfinite(depth)
        return {"depth": torch.from_numpy(np.where(hit, depth, 0.0) * outputs.dataparser_scale).float(),
                "directions_norm": torch.ones(height, width, 1), "accumulation": torch.from_numpy(hit).float()}

    monkeypatch.setattr(SSNeRFModel, "render_camera", render)


def test_normals_from_rendered_depth_match_those_from_the_true_depth(trained_scene, ray_caster_as_model,
                                                                     tmp_path: Path) -> None:
    scene, config_path = trained_scene
    truth = shutil.copytree(scene, tmp_path / "truth")
    label_dataset(LabelDatasetConfig(data=truth, relabel=True, shading=False, **ONLY_NORMALS), load_transforms(truth))
    data = without_depth(scene, tmp_path / "data")
    # (half the 40x30 images' resolution: the exact depth's normals need pixels more than the default's 10x8 give;
    # no smoothing, which is for a model's bumps and would round this exact depth's edges)
    label_dataset(LabelDatasetConfig(data=data, depth_from=config_path, depth_from_scale=0.5, depth_from_smoothing=0.0,
                                     **ONLY_NORMALS), load_transforms(data))

    frames = zip(json.loads((truth / "transforms.json").read_text())["frames"],
                 json.loads((data / "transforms.json").read_text())["frames"])
    true_normals, rendered = zip(*[(normals(truth / a["normals_file_path"]), normals(data / b["normals_file_path"]))
                                   for a, b in frames])
    facing = [np.broadcast_to([0.0, 0.0, 1.0], normal.shape) for normal in true_normals]  # a constant depth's
    assert median_angle(rendered, true_normals) < 2.0
    assert median_angle(facing, true_normals) > 10.0


def bad_config(make: Callable[[Path, Path], Path]) -> Callable[[Path, Path], List[str]]:
    def arguments(config: Path, folder: Path) -> List[str]:
        return ["--depth-from", str(make(config, folder))]
    return arguments


def no_checkpoint(config: Path, folder: Path) -> Path:
    trainer = yaml.load(config.read_text(), Loader=yaml.Loader)
    trainer.output_dir, trainer.timestamp = folder / "outputs", "empty"
    trainer.get_checkpoint_dir().mkdir(parents=True)
    (folder / "config.yml").write_text(yaml.dump(trainer))
    return folder / "config.yml"


def nerfacto(config: Path, folder: Path) -> Path:
    from nerfstudio.configs.method_configs import method_configs

    (folder / "config.yml").write_text(yaml.dump(method_configs["nerfacto"]))
    return folder / "config.yml"


def moved_poses(data: Path) -> None:
    meta = json.loads((data / "transforms.json").read_text())
    for frame in meta["frames"]:
        frame["transform_matrix"][0][3] += 0.5
    (data / "transforms.json").write_text(json.dumps(meta))


BAD: Dict[str, tuple] = {
    # name: (the --depth-from arguments, a change to the dataset or None, words the one line must hold)
    "missing file": (bad_config(lambda config, folder: folder / "nope.yml"), None, ["nope.yml", "no such file"]),
    "not a config": (bad_config(lambda config, folder: shutil.copy(config.parents[4] / "scene" / "transforms.json",
                                                                   folder / "transforms.yml")), None,
                     ["transforms.yml", "not a nerfstudio config.yml"]),
    "not an SS-NeRF": (bad_config(nerfacto), None, ["config.yml", "nerfacto", "not an SS-NeRF"]),
    "no checkpoint": (bad_config(no_checkpoint), None, ["empty", "holds no checkpoint"]),
    "trained on other poses": (bad_config(lambda config, folder: config), moved_poses,
                               ["config.yml", "another pose", "Train a model on this dataset"]),
    "scale out of range": (lambda config, folder: ["--depth-from", str(config), "--depth-from-scale", "2"], None,
                           ["--depth-from-scale 2", "(0, 1]"]),
    "smoothing out of range": (lambda config, folder: ["--depth-from", str(config), "--depth-from-smoothing", "-1"],
                               None, ["--depth-from-smoothing -1", "[0, 1)"]),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_config_one_line_nothing_written(case: str, trained_scene, tmp_path: Path, capsys, monkeypatch) -> None:
    scene, config_path = trained_scene
    arguments, change, words = BAD[case]
    data = without_depth(scene, tmp_path / "data")
    if change is not None:
        change(data)
    (tmp_path / "configs").mkdir()
    ssnerf_label_refuses(data, arguments(config_path, tmp_path / "configs"), words, capsys, monkeypatch)


def test_without_depth_from_ssnerf_label_trains_a_depth_model_on_every_frame(trained_scene, tmp_path: Path) -> None:
    """The default for a capture without depth: ssnerf-label trains an RGB-only model on every frame (held-out ones
    included) and labels normals and shading with its depth; the next run reuses the model."""
    scene, _ = trained_scene
    data = without_depth(scene, tmp_path / "data")
    config = LabelDatasetConfig(data=data, depth_model_steps=3, **ONLY_NORMALS)
    report = label_main(config)
    assert report.outcomes["normals"] == {LABELLED: 10} and report.outcomes["shading"] == {LABELLED: 10}
    model_config = data / "ssnerf_labels" / "depth_model" / "rgb" / "ssnerf-lite" / "steps3" / "config.yml"
    meta = json.loads((data / "transforms.json").read_text())
    assert meta["ssnerf_label"]["depth_from"]["config"] == str(model_config.resolve())
    trained = yaml.load(model_config.read_text(), Loader=yaml.Loader)
    assert trained.pipeline.model.properties == ()
    assert Path(trained.pipeline.datamanager.data).name == "transforms_depth_model.json"
    trained.pipeline.datamanager.dataparser.data = trained.pipeline.datamanager.data
    outputs = trained.pipeline.datamanager.dataparser.setup().get_dataparser_outputs("train")
    held_out = len(meta["test_filenames"])
    assert held_out > 0 and len(outputs.image_filenames) == 10  # every frame, the held-out ones too
    checkpoint = next((model_config.parent / "nerfstudio_models").glob("step-*.ckpt"))
    written = checkpoint.stat().st_mtime_ns
    label_main(LabelDatasetConfig(data=data, depth_model_steps=3, relabel=True, **ONLY_NORMALS))
    assert checkpoint.stat().st_mtime_ns == written  # reused, not trained again


def test_depth_model_steps_0_skips_normals_without_depth(trained_scene, tmp_path: Path) -> None:
    scene, _ = trained_scene
    data = without_depth(scene, tmp_path / "data")
    report = label_main(LabelDatasetConfig(data=data, depth_model_steps=0, **ONLY_NORMALS))
    assert report.outcomes["normals"].get(LABELLED, 0) == 0
    assert not (data / "ssnerf_labels" / "depth_model").exists()
