"""Loading the SS-NeRF dataset format: parser outputs, per-property labels, splits, missing labels and bad inputs."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Dict

import numpy as np
import pytest
import torch
from PIL import Image

from ssnerf_method.data.dataparser import SSNeRFDataParserConfig
from ssnerf_method.data.dataset import SSNeRFDataset
from ssnerf_method.data.pose_metadata import POSE_METADATA_KEY
from ssnerf_method.model.losses import LOSSES
from ssnerf_method.properties import OPTIONAL_PROPERTIES, REGISTRY, SEMANTIC_IGNORE, LabelFileError

from conftest import CLASSES, HEIGHT, WIDTH


def parse(root: Path, split: str = "train"):
    return SSNeRFDataParserConfig(data=root).setup().get_dataparser_outputs(split)


def load(root: Path, split: str = "train") -> SSNeRFDataset:
    return SSNeRFDataset(parse(root, split))


def index_of(dataset: SSNeRFDataset, frame_name: str) -> int:
    names = [Path(path).name for path in dataset.image_filenames]
    return names.index(frame_name)


def expected_label(root: Path, name: str, frame_name: str) -> torch.Tensor:
    array = np.asarray(Image.open(root / name / frame_name))
    if REGISTRY[name].kind.categorical:  # class ids as stored
        return torch.from_numpy(array.astype(np.float32))[..., None]
    tensor = torch.from_numpy(array.astype(np.float32) / 255.0)
    return tensor if tensor.ndim == 3 else tensor[..., None]


def test_parser_outputs_and_split(tiny_dataset: Path) -> None:
    train = parse(tiny_dataset, "train")
    test = parse(tiny_dataset, "test")
    assert sorted(Path(p).name for p in train.image_filenames) == [f"frame_{i:03d}.png" for i in range(1, 6)]
    assert [Path(p).name for p in test.image_filenames] == ["frame_000.png"]
    meta = train.metadata
    assert meta["semantic_classes"] == CLASSES
    assert tuple(meta["available_properties"]) == OPTIONAL_PROPERTIES
    for name in OPTIONAL_PROPERTIES:
        files = meta["property_files"][name]
        assert len(files) == len(train.image_filenames)
        # each label file belongs to its image
        for image, label in zip(train.image_filenames, files):
            assert Path(label).name == Path(image).name and Path(label).parent.name == name
    assert [Path(p).name for p in test.metadata["property_files"]["normals"]] == ["frame_000.png"]


def test_cameras_carry_pose_metadata(tiny_dataset: Path) -> None:
    outputs = parse(tiny_dataset)
    cameras = outputs.cameras
    pose = cameras.metadata[POSE_METADATA_KEY]
    assert pose.shape == (len(cameras), 12)
    assert torch.allclose(pose, cameras.camera_to_worlds.reshape(len(cameras), 12))
    rays = cameras.generate_rays(camera_indices=2, keep_shape=True)
    assert rays.metadata[POSE_METADATA_KEY].shape == (HEIGHT, WIDTH, 12)
    assert torch.allclose(rays.metadata[POSE_METADATA_KEY][3, 4], cameras.camera_to_worlds[2].reshape(12))


def test_dataset_items_decode_labels(tiny_dataset: Path) -> None:
    dataset = load(tiny_dataset)
    assert len(dataset) == 5
    for index in range(len(dataset)):
        item = dataset[index]
        frame_name = Path(dataset.image_filenames[index]).name
        image = np.asarray(Image.open(tiny_dataset / "images" / frame_name)).astype(np.float32) / 255.0
        assert item["image"].shape == (HEIGHT, WIDTH, 3)
        assert torch.allclose(item["image"], torch.from_numpy(image), atol=1e-6)
        for name in OPTIONAL_PROPERTIES:
            label = item[name]
            channels = REGISTRY[name].kind.label_channels(len(CLASSES))
            assert label.shape == (HEIGHT, WIDTH, channels), name
            assert label.dtype == torch.float32
            assert torch.allclose(label, expected_label(tiny_dataset, name, frame_name), atol=1e-6), name
            assert REGISTRY[name].kind.valid(label).all()
        assert set(item["semantics"].unique().tolist()) <= set(range(len(CLASSES)))
        assert item["normals"].max() <= 1.0 and item["shading"].min() >= 0.0


def test_semantic_ignore_value(tiny_dataset: Path) -> None:
    path = tiny_dataset / "semantics" / "frame_002.png"
    array = np.asarray(Image.open(path)).copy()
    array[0, :] = SEMANTIC_IGNORE
    Image.fromarray(array).save(path)
    dataset = load(tiny_dataset)
    label = dataset[index_of(dataset, "frame_002.png")]["semantics"]
    valid = REGISTRY["semantics"].kind.valid(label)
    assert (label[0, :, 0] == SEMANTIC_IGNORE).all()
    assert not valid[0].any() and valid[1:].all()


def _drop_key(key: str, frame_index: int):
    def change(transforms: Dict) -> None:
        del transforms["frames"][frame_index][key]

    return change


def test_frame_without_property_gets_ignored_label(tiny_dataset: Path, edit_transforms) -> None:
    edit_transforms(tiny_dataset, _drop_key("shading_file_path", 2))
    edit_transforms(tiny_dataset, _drop_key("semantics_file_path", 3))
    dataset = load(tiny_dataset)
    assert dataset.metadata["property_files"]["shading"][index_of(dataset, "frame_002.png")] is None
    shading = dataset[index_of(dataset, "frame_002.png")]["shading"]
    semantics = dataset[index_of(dataset, "frame_003.png")]["semantics"]
    assert shading.shape == (HEIGHT, WIDTH, 1) and torch.isnan(shading).all()
    assert semantics.shape == (HEIGHT, WIDTH, 1) and (semantics == SEMANTIC_IGNORE).all()
    # other frames keep their labels
    assert torch.isfinite(dataset[index_of(dataset, "frame_003.png")]["shading"]).all()
    assert (dataset[index_of(dataset, "frame_002.png")]["semantics"] < len(CLASSES)).all()

    # the loss masks exclude those rays: a batch mixing a labelled and an unlabelled frame's pixels
    labelled = dataset[index_of(dataset, "frame_003.png")]["shading"].reshape(-1, 1)
    label = torch.cat([labelled, shading.reshape(-1, 1)])
    prediction = torch.rand_like(label)
    valid = REGISTRY["shading"].kind.valid(label)
    assert valid.sum() == labelled.shape[0]
    loss = LOSSES["l1"](prediction, label, valid)
    assert torch.isfinite(loss)
    assert torch.isclose(loss, (prediction[: labelled.shape[0]] - labelled).abs().mean())
    sem_valid = REGISTRY["semantics"].kind.valid(semantics.reshape(-1, 1))
    assert not sem_valid.any()


def test_property_absent_from_every_frame_is_not_available(tiny_dataset: Path, edit_transforms) -> None:
    def change(transforms: Dict) -> None:
        for frame in transforms["frames"]:
            del frame["edges_file_path"]

    edit_transforms(tiny_dataset, change)
    dataset = load(tiny_dataset)
    assert "edges" not in dataset.metadata["available_properties"]
    assert "edges" not in dataset[0]


# ---------------------------------------------------------------------------------------------------- bad inputs


def _load_frame(root: Path, frame_name: str) -> Dict:
    dataset = load(root)
    return dataset[index_of(dataset, frame_name)]


def test_missing_label_file(tiny_dataset: Path) -> None:
    path = tiny_dataset / "normals" / "frame_002.png"
    path.unlink()
    with pytest.raises(LabelFileError, match=re.escape(str(path))) as info:
        _load_frame(tiny_dataset, "frame_002.png")
    assert "does not exist" in str(info.value)


def test_corrupt_label_file(tiny_dataset: Path) -> None:
    path = tiny_dataset / "edges" / "frame_003.png"
    path.write_bytes(np.random.default_rng(0).integers(0, 256, 500, dtype=np.uint8).tobytes())
    with pytest.raises(LabelFileError, match=re.escape(str(path))):
        _load_frame(tiny_dataset, "frame_003.png")


def test_truncated_png(tiny_dataset: Path) -> None:
    path = tiny_dataset / "shading" / "frame_001.png"
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(LabelFileError, match=re.escape(str(path))):
        _load_frame(tiny_dataset, "frame_001.png")


@pytest.mark.parametrize("name", ["shading", "semantics", "normals"])
def test_label_size_differs_from_camera(tiny_dataset: Path, name: str) -> None:
    path = tiny_dataset / name / "frame_004.png"
    shape = (HEIGHT - 4, WIDTH + 2, 3) if name == "normals" else (HEIGHT - 4, WIDTH + 2)
    Image.fromarray(np.zeros(shape, dtype=np.uint8)).save(path)
    with pytest.raises(LabelFileError, match=re.escape(str(path))) as info:
        _load_frame(tiny_dataset, "frame_004.png")
    assert f"{WIDTH}x{HEIGHT}" in str(info.value)


def test_semantic_id_outside_class_list(tiny_dataset: Path) -> None:
    path = tiny_dataset / "semantics" / "frame_005.png"
    array = np.zeros((HEIGHT, WIDTH), dtype=np.uint8)
    array[2, 3] = len(CLASSES) + 3
    Image.fromarray(array).save(path)
    with pytest.raises(LabelFileError, match=re.escape(str(path))) as info:
        _load_frame(tiny_dataset, "frame_005.png")
    assert str(len(CLASSES) + 3) in str(info.value)


@pytest.mark.parametrize("mode", ["L", "LA"])
def test_normals_not_three_channel(tiny_dataset: Path, mode: str) -> None:
    path = tiny_dataset / "normals" / "frame_001.png"
    channels = {"L": (), "LA": (2,)}[mode]
    Image.fromarray(np.full((HEIGHT, WIDTH, *channels), 128, dtype=np.uint8), mode=mode).save(path)
    with pytest.raises(LabelFileError, match=re.escape(str(path))):
        _load_frame(tiny_dataset, "frame_001.png")


@pytest.mark.parametrize("name, mode", [("normals", "RGBA"), ("shading", "LA")])
def test_alpha_zero_marks_unlabelled_pixels(tiny_dataset: Path, name: str, mode: str) -> None:
    """Labels derived from depth (normals, shading) carry alpha 0 where depth was invalid: those pixels get no loss."""
    path = tiny_dataset / name / "frame_001.png"
    array = np.full((HEIGHT, WIDTH, len(mode)), 200, dtype=np.uint8)
    array[:4, :5, -1] = 0
    Image.fromarray(array, mode=mode).save(path)
    label = _load_frame(tiny_dataset, "frame_001.png")[name]
    valid = REGISTRY[name].kind.valid(label)
    assert not valid[:4, :5].any() and valid.sum() == HEIGHT * WIDTH - 20
    assert torch.allclose(label[valid], torch.tensor(200 / 255.0))


def test_scalar_label_not_single_channel(tiny_dataset: Path) -> None:
    path = tiny_dataset / "keypoints" / "frame_001.png"
    Image.fromarray(np.zeros((HEIGHT, WIDTH, 3), dtype=np.uint8)).save(path)
    with pytest.raises(LabelFileError, match=re.escape(str(path))):
        _load_frame(tiny_dataset, "frame_001.png")


def test_semantics_without_class_list(tiny_dataset: Path, edit_transforms) -> None:
    edit_transforms(tiny_dataset, lambda transforms: transforms.pop("semantic_classes"))
    with pytest.raises(LabelFileError, match=re.escape(str(tiny_dataset / "transforms.json"))) as info:
        parse(tiny_dataset)
    assert "semantic_classes" in str(info.value)


def test_semantic_colors_must_match_classes(tiny_dataset: Path, edit_transforms) -> None:
    edit_transforms(tiny_dataset, lambda transforms: transforms.update(semantic_colors=[[0, 0, 0], [1, 2, 3]]))
    with pytest.raises(LabelFileError, match="transforms.json"):
        parse(tiny_dataset)


def test_folder_without_transforms(tmp_path: Path) -> None:
    folder = tmp_path / "empty"
    folder.mkdir()
    with pytest.raises((LabelFileError, FileNotFoundError), match=re.escape(str(folder / "transforms.json"))):
        parse(folder)


def test_bad_label_fails_at_datamanager_setup_before_training(tiny_dataset: Path) -> None:
    """The datamanager caches every training item when it is built, so a bad file stops the run before step 0."""
    from ssnerf_method.data.datamanager import SSNeRFDataManagerConfig

    path = tiny_dataset / "keypoints" / "frame_004.png"
    path.unlink()
    config = SSNeRFDataManagerConfig(data=tiny_dataset)
    config.dataparser.data = tiny_dataset
    with pytest.raises(LabelFileError, match=re.escape(str(path))):
        config.setup(device="cpu", test_mode="val", world_size=1, local_rank=0)
