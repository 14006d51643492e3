"""Knowledge transfer (Table 5): `encoder_init` copies F_enc, and only F_enc, from a checkpoint before the first step;
the k training views are evenly spaced; the k-view dataset keeps the scene's poses frame and test split."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from nerfstudio.engine.callbacks import TrainingCallbackAttributes, TrainingCallbackLocation

from ssnerf_method.data.dataparser import SSNeRFDataParserConfig
from ssnerf_method.experiments.transfer import evenly_spaced, make_limited_dataset
from ssnerf_method.model.encoder_transfer import EncoderTransferError

from test_rendering import tiny_model


def save_checkpoint(model: torch.nn.Module, path: Path) -> Path:
    """A nerfstudio-style checkpoint of `model` (its entries under the pipeline's `_model.` prefix)."""
    torch.save({"step": 9, "pipeline": {f"_model.{key}": value for key, value in model.state_dict().items()}}, path)
    return path


def run_callbacks(model, step: int) -> None:
    attributes = TrainingCallbackAttributes(optimizers=None, grad_scaler=None, pipeline=None, trainer=None)
    for callback in model.get_training_callbacks(attributes):
        callback.run_callback_at_location(step, TrainingCallbackLocation.BEFORE_TRAIN_ITERATION)


def split(model, part: str):
    """The model's trainable weights whose path has `part` in it (e.g. ".encoder.") and the others."""
    weights = {key: value.detach().clone() for key, value in model.named_parameters()
               if key != "device_indicator_param"}
    return ({key: value for key, value in weights.items() if part in key},
            {key: value for key, value in weights.items() if part not in key})


@pytest.mark.parametrize("sampling", ["hierarchical", "proposal"])
def test_encoder_init_copies_only_f_enc_before_the_first_step(tmp_path: Path, sampling: str) -> None:
    torch.manual_seed(0)
    source = tiny_model(properties=("semantics",), sampling=sampling)
    checkpoint = save_checkpoint(source, tmp_path / "step-000000009.ckpt")
    torch.manual_seed(1)
    target = tiny_model(properties=("shading",), sampling=sampling, encoder_init=checkpoint)
    source_encoders, source_rest = split(source, ".encoder.")
    fresh_encoders, fresh_rest = split(target, ".encoder.")
    assert source_encoders and all(not torch.equal(fresh_encoders[k], v) for k, v in source_encoders.items())

    run_callbacks(target, step=0)
    encoders, rest = split(target, ".encoder.")
    assert all(torch.equal(encoders[key], value) for key, value in source_encoders.items())
    # decoders, heads and proposal networks keep their own fresh weights
    assert all(torch.equal(rest[key], value) for key, value in fresh_rest.items())
    shared = [key for key in rest if key in source_rest and rest[key].shape == source_rest[key].shape]
    assert shared and not any(torch.equal(rest[key], source_rest[key]) for key in shared)
    if sampling == "hierarchical":  # both the coarse and the fine field's F_enc
        assert {key.split(".encoder.")[0] for key in encoders} == {"sampling.coarse_field", "sampling.fine_field"}

    # a later step (a resumed run) does not copy again
    with torch.no_grad():
        next(target.sampling.parameters()).add_(1.0)
    trained = {key: value.clone() for key, value in target.state_dict().items()}
    run_callbacks(target, step=1)
    assert all(torch.equal(target.state_dict()[key], value) for key, value in trained.items())


def test_encoder_init_from_another_architecture_names_the_file(tmp_path: Path) -> None:
    checkpoint = save_checkpoint(tiny_model(grid_levels=3), tmp_path / "other.ckpt")
    target = tiny_model(encoder_init=checkpoint)
    with pytest.raises(EncoderTransferError, match="other.ckpt.*does not match"):
        run_callbacks(target, step=0)
    missing = tiny_model(encoder_init=tmp_path / "missing.ckpt")
    with pytest.raises(EncoderTransferError, match="missing.ckpt: no such checkpoint"):
        run_callbacks(missing, step=0)


def test_views_are_evenly_spaced_along_the_trajectory() -> None:
    names = [f"frame_{i:02d}" for i in range(48)]
    assert evenly_spaced(names, 6) == ["frame_00", "frame_09", "frame_19", "frame_28", "frame_38", "frame_47"]
    assert evenly_spaced(names, 1) == ["frame_00"] and evenly_spaced(names, 48) == names
    with pytest.raises(ValueError, match="--views 49"):
        evenly_spaced(names, 49)


def test_limited_dataset_keeps_the_frame_and_the_test_split(tiny_dataset: Path, tmp_path: Path) -> None:
    before = (tiny_dataset / "transforms.json").read_text()
    chosen = make_limited_dataset(tiny_dataset, tmp_path / "limited", 2)
    assert chosen == ["images/frame_001.png", "images/frame_005.png"]
    assert (tiny_dataset / "transforms.json").read_text() == before  # the scene is untouched
    full = SSNeRFDataParserConfig(data=tiny_dataset).setup()
    limited = SSNeRFDataParserConfig(data=tmp_path / "limited").setup()
    train, full_train = limited.get_dataparser_outputs("train"), full.get_dataparser_outputs("train")
    assert [Path(name).name for name in train.image_filenames] == ["frame_001.png", "frame_005.png"]
    # same poses frame as the model trained on every view (F_enc is transferred in it)
    assert torch.allclose(train.cameras.camera_to_worlds, full_train.cameras.camera_to_worlds[[0, 4]])
    assert train.dataparser_scale == full_train.dataparser_scale
    assert train.metadata["property_files"]["semantics"][1] == tiny_dataset / "semantics" / "frame_005.png"
    test = limited.get_dataparser_outputs("test")
    assert [Path(name).name for name in test.image_filenames] == ["frame_000.png"]
    meta = json.loads((tmp_path / "limited" / "transforms.json").read_text())
    assert meta["ssnerf_limited_views"]["train_filenames"] == chosen
