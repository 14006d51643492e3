"""The two registered methods: `ssnerf` (the paper's sizes, for a GPU) and `ssnerf-lite` (same split, CPU-sized).

Both are the same model and data pipeline; `ssnerf-lite` swaps the positional-encoding MLP of F_enc for nerfstudio's
hash grid and NeRF's coarse/fine fields for nerfstudio's proposal sampler, which is what makes minutes on 2 CPU
cores enough (see ../shared/notes/cpu-speed.md in the project's notes).
"""

from __future__ import annotations

from copy import deepcopy
from pathlib import Path
from typing import Optional

import torch

from nerfstudio.configs.base_config import MachineConfig, ViewerConfig
from nerfstudio.engine.schedulers import ExponentialDecaySchedulerConfig
from nerfstudio.engine.trainer import TrainerConfig
from nerfstudio.plugins.types import MethodSpecification

from ssnerf_method.data.datamanager import SSNeRFDataManagerConfig
from ssnerf_method.engine.optimizers import FusedAdamOptimizerConfig
from ssnerf_method.engine.trainer import SSNeRFTrainerConfig
from ssnerf_method.model.loss_balancing import LossBalancerConfig
from ssnerf_method.model.ssnerf_model import SSNeRFModelConfig
from ssnerf_method.pipelines.ssnerf_pipeline import SSNeRFPipelineConfig
from ssnerf_method.viewer.host import LOCAL_HOST

SHORT_RUN_STEPS = {"ssnerf-lite": 1000, "ssnerf": 20000}
"""Training steps of a short run per method, the benchmark's and the studies' default (the methods' own
`max_num_iterations` are for full-quality runs; the demo has its own, `scripts.demo.DEMO_STEPS`)."""

SPARE_CLASSES = 4
"""Semantic class slots the viewer's Label panel can add classes to while a run trains (`spare_classes`)."""


def default_machine() -> MachineConfig:
    """Train on CUDA when there is a GPU, else on the CPU (nerfstudio's default would fail without CUDA)."""
    return MachineConfig(device_type="cuda" if torch.cuda.is_available() else "cpu")


ssnerf_config = SSNeRFTrainerConfig(
    method_name="ssnerf",
    steps_per_eval_batch=500,
    steps_per_eval_image=2500,
    steps_per_save=5000,
    max_num_iterations=200000,
    mixed_precision=False,
    machine=default_machine(),
    pipeline=SSNeRFPipelineConfig(
        datamanager=SSNeRFDataManagerConfig(train_num_rays_per_batch=1024, eval_num_rays_per_batch=1024),
        model=SSNeRFModelConfig(eval_num_rays_per_chunk=4096, spare_classes=SPARE_CLASSES),
    ),
    optimizers={
        "fields": {
            "optimizer": FusedAdamOptimizerConfig(lr=5e-4, eps=1e-8),
            # The authors decay by 0.1 over 250k steps: 5e-4 -> 5e-5.
            "scheduler": ExponentialDecaySchedulerConfig(lr_final=5e-5, max_steps=250000),
        },
    },
    viewer=ViewerConfig(num_rays_per_chunk=4096, websocket_host=LOCAL_HOST),
    vis="viewer+tensorboard",
)

ssnerf_lite_config = SSNeRFTrainerConfig(
    method_name="ssnerf-lite",
    steps_per_eval_batch=500,
    steps_per_eval_image=5000,
    steps_per_eval_all_images=1000000,
    steps_per_save=2000,
    max_num_iterations=30000,
    mixed_precision=False,
    machine=default_machine(),
    pipeline=SSNeRFPipelineConfig(
        datamanager=SSNeRFDataManagerConfig(train_num_rays_per_batch=1024, eval_num_rays_per_batch=1024),
        model=SSNeRFModelConfig(
            eval_num_rays_per_chunk=8192,
            encoder="hashgrid",
            direction_encoding="sh",
            decoder_width=64,
            decoder_layers=2,
            density_noise=0.0,
            density_activation="trunc_exp",
            sampling="proposal",
            num_proposal_samples=(64, 32),
            num_field_samples=32,
            far_plane=1000.0,
            # The paper's L1 drives 1-pixel edge maps to an empty map within a CPU budget; MSE renders them, and on
            # the keypoint response map it weights the peaks' large errors more (higher keypoint F1, 2026-12-03).
            losses={"edges": "mse", "keypoints": "mse"},
            # Properties' gradients into F_enc dwarf RGB's at the start and Adam lets them set its updates: each is
            # capped at a tenth of RGB's, and each property has its own decoder MLP on a 32-number feature
            # (docs/method.md, "Multi-task balancing").
            balancing=LossBalancerConfig(ratio=0.1),
            decoder_sharing="property",
            grid_feature_dim=32,
            # Sparse semantic labels (clicks, viewer strokes) spread through a coarse grid and, for the semantics
            # decoder, sinusoids of the position that carry a class along a surface past its labels (`ssnerf-study
            # propagation`, docs/results/); normals, shading and keypoints lose e_x's speckle through the same grid
            # (`ssnerf-study class-grid`); edges do not gain from it.
            class_grid_max_res=128,
            class_grid_frequencies=4,
            class_grid_properties=("semantics", "normals", "shading", "keypoints"),
            spare_classes=SPARE_CLASSES,
        ),
    ),
    optimizers={
        "proposal_networks": {
            "optimizer": FusedAdamOptimizerConfig(lr=1e-2, eps=1e-15),
            "scheduler": ExponentialDecaySchedulerConfig(lr_final=1e-4, max_steps=30000),
        },
        "fields": {
            "optimizer": FusedAdamOptimizerConfig(lr=1e-2, eps=1e-15),
            "scheduler": ExponentialDecaySchedulerConfig(lr_final=1e-4, max_steps=30000),
        },
    },
    viewer=ViewerConfig(num_rays_per_chunk=8192, websocket_host=LOCAL_HOST),
    vis="viewer+tensorboard",
)



def short_run(method: str, data: Path, output_dir: Path, steps: Optional[int] = None) -> TrainerConfig:
    """A copy of `method`'s trainer config for a short run on `data`, as the demo and the benchmark train: its
    `SHORT_RUN_STEPS` (or `steps`), TensorBoard logging instead of the viewer, one checkpoint at the end and no
    evaluation while training (both evaluate the final checkpoint as `ns-eval` does)."""
    trainer = deepcopy(ssnerf_config if method == "ssnerf" else ssnerf_lite_config)
    steps = steps or SHORT_RUN_STEPS[method]
    trainer.pipeline.datamanager.data = data  # type: ignore[attr-defined]
    trainer.output_dir = output_dir
    trainer.vis = "tensorboard"
    trainer.max_num_iterations = trainer.steps_per_save = steps
    trainer.steps_per_eval_image = trainer.steps_per_eval_all_images = trainer.steps_per_eval_batch = steps + 1
    return trainer


ssnerf = MethodSpecification(
    config=ssnerf_config,
    description="SS-NeRF (paper sizes): RGB + semantics, normals, shading, keypoints, edges from one NeRF.",
)
ssnerf_lite = MethodSpecification(
    config=ssnerf_lite_config,
    description="SS-NeRF with a hash-grid encoder and proposal sampling: trains on a CPU in minutes.",
)
