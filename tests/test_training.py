"""Short CPU training runs of `ssnerf-lite` and `ssnerf`: losses drop, every property is supervised, and a saved
checkpoint loads back through nerfstudio's `eval_setup` and renders every property."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Dict, List, Tuple

import numpy as np
import pytest
import torch
from PIL import Image

from nerfstudio.engine.trainer import Trainer, TrainerConfig
from nerfstudio.utils.eval_utils import eval_setup

from ssnerf_method.engine.trainer import train_in_process
from ssnerf_method.experiments.benchmark import shrink_for_quick
from ssnerf_method.method_configs import SPARE_CLASSES, ssnerf_config, ssnerf_lite_config
from ssnerf_method.metrics import METRICS
from ssnerf_method.properties import OPTIONAL_PROPERTIES, REGISTRY

from conftest import CLASSES, HEIGHT, WIDTH, write_tiny_dataset

EXPECTED_OUTPUTS = {
    **{spec.name: 3 for spec in REGISTRY.values()},
    **{spec.prediction_key: spec.kind.head_channels(len(CLASSES) + SPARE_CLASSES) for spec in REGISTRY.values()
       if spec.kind.prediction_suffix},
}
"""`render_camera`'s outputs (display images, and the predictions stored apart from them) and their channels (class
logits: the dataset's classes and the spare slots the viewer's Label panel can name)."""
DISPLAY_EXTRAS = {extra for name, spec in REGISTRY.items() for extra in spec.kind.display_extras(name)}
"""One-channel maps shown beside the properties' images (the class uncertainty)."""
DISPLAY_OUTPUTS = {*REGISTRY, *DISPLAY_EXTRAS, "depth", "accumulation"}
"""What the viewer lists and `ns-render` can write: nothing internal."""


@pytest.fixture(scope="module", autouse=True)
def single_thread():
    """One intra-op thread: on a 2-core machine shared with other jobs, torch's thread pool stalls badly (a step
    takes ~0.03 s on one thread and up to 2 s on two when the other core is busy)."""
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)


def write_learnable_dataset(root: Path) -> Path:
    """The tiny dataset's cameras and layout, with smooth labels instead of per-frame noise.

    Every map is a gentle vertical gradient around a value far from an untrained field's output (sigmoid 0.5, ReLU
    0, uniform class logits), so each property's loss has room to drop within a few dozen steps.
    """
    transforms = write_tiny_dataset(root)
    rows = np.linspace(0.0, 1.0, HEIGHT)[:, None] * np.ones((1, WIDTH))
    for frame in transforms["frames"]:
        name = Path(frame["file_path"]).name
        rgb = np.stack([0.9 - 0.2 * rows, 0.15 + 0.1 * rows, np.full_like(rows, 0.1)], axis=-1)
        Image.fromarray((rgb * 255).astype(np.uint8)).save(root / "images" / name)
        Image.fromarray(np.where(rows < 0.5, 1, 2).astype(np.uint8)).save(root / "semantics" / name)
        normals = np.zeros((HEIGHT, WIDTH, 3), dtype=np.uint8)
        normals[..., :] = (128, 128, 255)
        Image.fromarray(normals).save(root / "normals" / name)
        Image.fromarray(((0.85 + 0.1 * rows) * 255).astype(np.uint8)).save(root / "shading" / name)
        Image.fromarray(np.full((HEIGHT, WIDTH), 180, dtype=np.uint8)).save(root / "keypoints" / name)
        Image.fromarray(((0.05 + 0.1 * rows) * 255).astype(np.uint8)).save(root / "edges" / name)
    return root


def lite_config(data: Path, output: Path, iterations: int) -> TrainerConfig:
    config = copy.deepcopy(ssnerf_lite_config)
    config.pipeline.datamanager.data = data
    shrink_for_quick(config)  # the benchmark's --quick sizes
    config.pipeline.model.eval_num_rays_per_chunk = 1024
    _common(config, output, iterations)
    return config


def _common(config: TrainerConfig, output: Path, iterations: int) -> None:
    config.machine.device_type = "cpu"
    config.machine.num_devices = 1
    config.vis = "tensorboard"
    config.viewer.quit_on_train_completion = True
    config.output_dir = output
    config.experiment_name = "test"
    config.timestamp = "run"
    config.max_num_iterations = iterations
    config.steps_per_eval_batch = 10**6
    config.steps_per_eval_image = 10**6
    config.steps_per_eval_all_images = 10**6
    config.logging.local_writer.enable = False


def train(config: TrainerConfig) -> Tuple[Trainer, List[float], List[Dict[str, float]]]:
    """Run nerfstudio's Trainer as `ns-train` does, recording each step's total loss and loss dict."""
    torch.manual_seed(0)
    config.save_config()
    trainer = config.setup(local_rank=0, world_size=1)
    trainer.setup()
    totals: List[float] = []
    dicts: List[Dict[str, float]] = []
    original = trainer.train_iteration

    def recording(step: int):
        loss, loss_dict, metrics_dict = original(step)
        totals.append(float(loss))
        dicts.append({key: float(value) for key, value in loss_dict.items()})
        return loss, loss_dict, metrics_dict

    trainer.train_iteration = recording  # type: ignore[method-assign]
    trainer.train()
    return trainer, totals, dicts


@pytest.fixture(scope="module")
def lite_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("learnable")
    data = write_learnable_dataset(root / "data")
    config = lite_config(data, root / "outputs", iterations=60)
    config.steps_per_save = 25
    config.save_only_latest_checkpoint = True
    trainer, totals, dicts = train(config)
    return config, trainer, totals, dicts


def test_lite_losses_drop(lite_run) -> None:
    _, _, totals, _ = lite_run
    assert len(totals) == 60
    assert all(np.isfinite(totals))
    first = float(np.mean(totals[:3]))
    last = float(np.mean(totals[-10:]))
    assert last < 0.6 * first, (first, last)


def test_lite_every_property_is_supervised(lite_run) -> None:
    _, _, _, dicts = lite_run
    expected = {f"{name}_loss" for name in ("rgb", *OPTIONAL_PROPERTIES)} | {"interlevel_loss", "distortion_loss"}
    for loss_dict in dicts:
        assert set(loss_dict) == expected
    for name in ("rgb", *OPTIONAL_PROPERTIES):
        values = [loss_dict[f"{name}_loss"] for loss_dict in dicts]
        assert np.mean(values[-10:]) < np.mean(values[:3]), name


def test_lite_checkpoint_round_trip(lite_run) -> None:
    config, _, _, _ = lite_run
    checkpoints = sorted(config.get_checkpoint_dir().glob("*.ckpt"))
    assert [path.name for path in checkpoints] == ["step-000000059.ckpt"]  # only the latest is kept
    config_path = config.get_base_dir() / "config.yml"
    assert config_path.is_file()

    _, pipeline, checkpoint_path, step = eval_setup(config_path)
    assert checkpoint_path == checkpoints[0] and step == 59
    dataset = pipeline.datamanager.eval_dataset
    assert [Path(p).name for p in dataset.image_filenames] == ["frame_000.png"]
    camera = dataset.cameras[0:1]
    outputs = pipeline.model.render_camera(camera)
    for name, channels in EXPECTED_OUTPUTS.items():
        assert outputs[name].shape == (HEIGHT, WIDTH, channels), name
        assert torch.isfinite(outputs[name]).all(), name
    shown = pipeline.model.get_outputs_for_camera(camera)  # the viewer's and ns-render's call
    assert set(shown) == DISPLAY_OUTPUTS
    for name in DISPLAY_OUTPUTS - DISPLAY_EXTRAS - {"depth", "accumulation"}:
        assert shown[name].shape == (HEIGHT, WIDTH, 3) and torch.equal(shown[name], outputs[name]), name
    assert DISPLAY_EXTRAS == {"semantics_uncertainty"}
    for name in DISPLAY_EXTRAS:
        assert shown[name].shape == (HEIGHT, WIDTH, 1) and 0.0 <= shown[name].min() <= shown[name].max() <= 1.0, name
    # scalar maps are shown in the fixed range [0, 1] (grey): a value of v is the colour (v, v, v)
    assert torch.allclose(shown["shading"], outputs["shading_value"].clamp(0, 1).expand(-1, -1, 3))
    # the loaded weights are the trained ones: the test view's colour is learnt, not the init's grey
    image = dataset[0]["image"]
    assert torch.mean((outputs["rgb"] - image) ** 2) < 0.03

    metrics = pipeline.get_average_eval_image_metrics()
    for spec in REGISTRY.values():  # every property's headline number
        key = spec.metric_prefix + METRICS[spec.metric].reported[0][0]
        assert key in metrics and np.isfinite(metrics[key]), key
    assert metrics["psnr"] > 12
    assert 0.0 <= metrics["semantics_miou"] <= 1.0
    # the demo's hook gets each scored view's own render, so its PNGs need no second pass
    seen = []
    hooked = pipeline.get_average_image_metrics(
        pipeline.datamanager.fixed_indices_eval_dataloader, "eval",
        on_view=lambda index, camera, batch, out: seen.append((index, batch["image"], out)),
    )
    assert [index for index, _, _ in seen] == [0]
    assert torch.equal(seen[0][1], image)
    assert torch.allclose(seen[0][2]["rgb"], outputs["rgb"], atol=1e-6)
    assert hooked["psnr"] == pytest.approx(metrics["psnr"], abs=1e-6)


def test_hierarchical_pose_normals_runs_on_cpu(tmp_path: Path) -> None:
    data = write_learnable_dataset(tmp_path / "data")
    config = copy.deepcopy(ssnerf_config)
    config.pipeline.datamanager.data = data
    config.pipeline.datamanager.train_num_rays_per_batch = 64
    config.pipeline.datamanager.eval_num_rays_per_batch = 64
    model = config.pipeline.model
    model.encoder_layers = 2
    model.encoder_width = 32
    model.decoder_width = 32
    model.num_coarse_samples = 8
    model.num_fine_samples = 8
    model.normals_mode = "pose"
    model.eval_num_rays_per_chunk = 1024
    _common(config, tmp_path / "outputs", iterations=4)
    config.steps_per_save = 10**6
    trainer, totals, dicts = train(config)
    assert len(totals) == 4 and all(np.isfinite(totals))
    expected = {f"{prefix}{name}_loss" for prefix in ("", "level0_") for name in ("rgb", *OPTIONAL_PROPERTIES)}
    for loss_dict in dicts:
        assert set(loss_dict) == expected
    pipeline = trainer.pipeline
    pipeline.eval()
    outputs = pipeline.model.render_camera(pipeline.datamanager.eval_dataset.cameras[0:1])
    for name, channels in EXPECTED_OUTPUTS.items():
        assert outputs[name].shape == (HEIGHT, WIDTH, channels), name
    assert ((outputs["normals"] >= 0) & (outputs["normals"] <= 1)).all()
    assert "level0_semantics_logits" in outputs


def test_configs_saved_before_the_pipeline_moved_still_load() -> None:
    """Runs trained before `pipelines/ssnerf_pipeline.py` existed name `ssnerf_method.evaluation.pipeline` in their
    config.yml; nerfstudio's loader must still build today's pipeline from them."""
    import yaml

    from ssnerf_method.pipelines.ssnerf_pipeline import SSNeRFPipeline, SSNeRFPipelineConfig

    text = ("!!python/object:ssnerf_method.evaluation.pipeline.SSNeRFPipelineConfig\n"
            "_target: !!python/name:ssnerf_method.evaluation.pipeline.SSNeRFPipeline ''\n")
    config = yaml.load(text, Loader=yaml.Loader)
    assert isinstance(config, SSNeRFPipelineConfig) and config._target is SSNeRFPipeline


def test_trainings_in_one_process_each_log_only_into_their_own_event_file(tmp_path, monkeypatch):
    """nerfstudio keeps its event writers and profilers in module-level lists; `train_in_process` takes out those a
    training added, so that the next training in the process (a study's next run) does not also log into this one's
    file."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    from nerfstudio.scripts import train
    from nerfstudio.utils import profiler, writer

    def training(config: TrainerConfig) -> None:
        """What a training does with its writers: set them up, log, and flush every writer there is."""
        profiler.setup_profiler(config.logging, config.output_dir)
        writer.setup_event_writer(False, True, False, log_dir=config.output_dir, experiment_name="run")
        writer.put_scalar("loss", float(config.max_num_iterations), step=0)
        writer.write_out_storage()
        for each in writer.EVENT_WRITERS:
            each.tb_writer.flush()

    monkeypatch.setattr(writer, "EVENT_WRITERS", [])
    monkeypatch.setattr(profiler, "PROFILER", [])
    monkeypatch.setattr(train, "main", training)
    for run in (1, 2):
        train_in_process(TrainerConfig(output_dir=tmp_path / f"run{run}", max_num_iterations=run))
    assert writer.EVENT_WRITERS == [] and profiler.PROFILER == []
    for run in (1, 2):
        events = EventAccumulator(str(tmp_path / f"run{run}"))
        events.Reload()
        assert [event.value for event in events.Scalars("loss")] == [run]
