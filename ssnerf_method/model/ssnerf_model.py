"""SS-NeRF model: renders RGB and every enabled scene property from one shared field (paper Sec. 3.3).

Everything per property (heads, rendering, loss, metric, display) is read from the registry in
`ssnerf_method/properties.py`, and every optional training term from `model/regularisers/`; this module wires the
field, the sampling strategy, the paper's losses and nerfstudio's hooks.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, List, Literal, Optional, Tuple, Type

import torch
from torch import Tensor, nn

from nerfstudio.cameras.cameras import Cameras
from nerfstudio.cameras.rays import RayBundle
from nerfstudio.engine.callbacks import TrainingCallback, TrainingCallbackAttributes, TrainingCallbackLocation
from nerfstudio.model_components.losses import distortion_loss, interlevel_loss
from nerfstudio.model_components.renderers import AccumulationRenderer, DepthRenderer
from nerfstudio.model_components.scene_colliders import NearFarCollider
from nerfstudio.models.base_model import Model, ModelConfig
from nerfstudio.utils import colormaps
from nerfstudio.utils.rich_utils import CONSOLE

from ssnerf_method.data.dataset import DEPTH_KEY
from ssnerf_method.data.pose_metadata import POSE_METADATA_KEY, add_pose_metadata
from ssnerf_method.fields.compiled import CompileConfig
from ssnerf_method.fields.encoders import gather_hash_lookups
from ssnerf_method.fields.ssnerf_field import DecoderSharing
from ssnerf_method.metrics import DEPTH_METRIC, METRICS, Statistics, summarize
from ssnerf_method.model.config_upgrade import upgrade_model_state
from ssnerf_method.model.encoder_transfer import encoder_modules, load_encoders
from ssnerf_method.model.field_builder import build_sampling
from ssnerf_method.model.loss_balancing import LossBalancer, LossBalancerConfig
from ssnerf_method.model.losses import LOSSES
from ssnerf_method.model.regularisers import Regulariser, RegulariserConfig, default_regularisers
from ssnerf_method.properties import (
    OPTIONAL_PROPERTIES,
    UNNAMED_LOGIT,
    Branch,
    ClassKind,
    LossName,
    PropertySpec,
    RenderContext,
    class_property,
    resolve_properties,
)
from ssnerf_method.rendering.depth import rendered_z_depth
from ssnerf_method.rendering.palette import semantic_palette
from ssnerf_method.rendering.sampling import (
    RaySampling,
    SampleLevel,
    SamplingResult,
)
from ssnerf_method.viewer.semantic_panel import SemanticViewerPanel, highlight_class

CLASS_GRID_PROPERTIES: Tuple[str, ...] = (class_property().name,)
"""The properties that see the class grid unless a config names others (runs saved before the option had it)."""


@dataclass
class SSNeRFModelConfig(ModelConfig):
    """SS-NeRF model configuration. Defaults are the paper's (`ssnerf`); `ssnerf-lite` overrides the sizes."""

    _target: Type = field(default_factory=lambda: SSNeRFModel)
    properties: Tuple[str, ...] = OPTIONAL_PROPERTIES
    """Properties to render besides RGB (always on); any subset of the registry's."""
    branches: Dict[str, Branch] = field(default_factory=dict)
    """Per-property decoder branch overrides, e.g. {semantics: v} (paper Table 3); unset = the paper's choice."""
    loss_weights: Dict[str, float] = field(default_factory=dict)
    """Per-property loss weight overrides; unset = the paper's lambda."""
    losses: Dict[str, LossName] = field(default_factory=dict)
    """Per-property loss overrides, e.g. {edges: mse}; unset = the paper's loss."""
    normals_mode: Literal["world", "pose"] = "world"
    """World-frame normals rotated into the camera after rendering, or the paper's pose-conditioned F_dec^nv."""
    encoder: Literal["positional", "hashgrid"] = "positional"
    """F_enc: NeRF positional encoding + MLP (the paper's), or a multi-resolution hash grid + small MLP (lite)."""
    encoder_layers: int = 8
    """Positional encoder: MLP depth (skip connection after the 4th layer)."""
    encoder_width: int = 256
    """Positional encoder: MLP width (also the feature size)."""
    grid_levels: int = 12
    """Hash grid: number of resolution levels."""
    grid_max_res: int = 512
    """Hash grid: finest resolution."""
    grid_log2_hashmap_size: int = 17
    """Hash grid: log2 of the table size per level."""
    grid_hidden_dim: int = 64
    """Hash grid: width of the MLP after the grid."""
    grid_feature_dim: int = 15
    """Hash grid: size of the feature e_x passed to the decoders."""
    class_grid_max_res: int = 0
    """If > 0, the decoders of `class_grid_properties` also see a coarse, smooth hash grid of their own (4 levels, 16
    up to this resolution), through which sparse labels spread to the surfaces around them. 0: the paper's decoders."""
    class_grid_frequencies: int = 0
    """If > 0, the class-valued decoder also sees sinusoids of the position at this many octaves, smooth where the
    grid is blank, so a class carries on along a surface past its labels. 0: the grid alone."""
    class_grid_properties: Tuple[str, ...] = CLASS_GRID_PROPERTIES
    """Properties whose decoder MLP sees the class grid (each has an MLP of its own)."""
    direction_encoding: Literal["nerf", "sh"] = "nerf"
    """View-direction encoding of F_dec^v: 4-frequency sinusoids (paper) or spherical harmonics."""
    decoder_width: int = 128
    """Width of each decoder branch."""
    decoder_layers: int = 1
    """Hidden layers of each decoder branch."""
    decoder_sharing: DecoderSharing = "branch"
    """One decoder MLP per branch (the paper's F_dec^v, F_dec^nv), or one per property on its branch's inputs."""
    density_noise: float = 1.0
    """Std of noise added to raw density while training (NeRF); 0 disables."""
    density_activation: Literal["relu", "trunc_exp"] = "relu"
    """Density activation: ReLU (NeRF) or truncated exponential (grid encoders)."""
    sampling: Literal["hierarchical", "proposal"] = "hierarchical"
    """Coarse + fine fields (paper), or nerfstudio's proposal sampler in front of one field (lite)."""
    num_coarse_samples: int = 64
    """Hierarchical: uniform samples per ray through the coarse field."""
    num_fine_samples: int = 64
    """Hierarchical: importance samples per ray added for the fine field."""
    num_proposal_samples: Tuple[int, ...] = (64, 32)
    """Proposal: samples per ray of each proposal network iteration."""
    num_field_samples: int = 32
    """Proposal: samples per ray through the field."""
    proposal_max_res: Tuple[int, ...] = (128, 256)
    """Proposal: finest grid resolution of each proposal network."""
    interlevel_loss_mult: float = 1.0
    """Proposal: weight of the loss that teaches the proposals the field's weights."""
    distortion_loss_mult: float = 0.002
    """Proposal: weight of the distortion loss (mip-NeRF 360)."""
    proposal_weights_anneal_max_num_iters: int = 1000
    """Proposal: steps over which the proposal weights are annealed."""
    near_plane: float = 0.05
    """Near plane, in the dataparser's scaled units."""
    far_plane: float = 6.0
    """Far plane, in the dataparser's scaled units (cameras lie within [-1, 1] after scaling)."""
    implementation: Literal["tcnn", "torch"] = "torch"
    """Hash grid implementation (tcnn needs tiny-cuda-nn on CUDA)."""
    compile: CompileConfig = field(default_factory=CompileConfig)
    """CPU training through `torch.compile` (`fields/compiled.py`)."""
    balancing: LossBalancerConfig = field(default_factory=LossBalancerConfig)
    """Gradient-norm balancing of the property losses against RGB's (`model/loss_balancing.py`)."""
    regularisers: Dict[str, RegulariserConfig] = field(default_factory=default_regularisers)
    """The optional training terms by name (`model/regularisers/`); all off (`mult` 0) but the semantic affinity."""
    spare_classes: int = 0
    """Class slots beyond the dataset's, for classes added in the viewer's Label panel while training."""
    encoder_init: Optional[Path] = None
    """A trained SS-NeRF's checkpoint (same method) whose F_enc initialises this one's (the paper's Table 5)."""

    def __setstate__(self, state: Dict[str, Any]) -> None:
        """A config.yml saved before the current layout loads into it (`config_upgrade.py`)."""
        self.__dict__.update(upgrade_model_state(state))


class SSNeRFModel(Model):
    """Scene-property synthesis with one shared radiance field."""

    config: SSNeRFModelConfig

    def populate_modules(self) -> None:
        super().populate_modules()
        metadata = self.kwargs.get("metadata") or {}
        self.class_names: List[str] = list(metadata.get("semantic_classes") or [])
        available = metadata.get("available_properties", OPTIONAL_PROPERTIES)
        dropped = [name for name in self.config.properties if name not in available]
        if dropped:
            CONSOLE.print(f"[yellow]The dataset has no labels for {dropped}: they are not trained.")
        self.specs: List[PropertySpec] = resolve_properties(
            [name for name in self.config.properties if name in available], branches=self.config.branches,
            weights=self.config.loss_weights, normals_mode=self.config.normals_mode, losses=self.config.losses,
        )
        self.class_spec = next((spec for spec in self.specs if isinstance(spec.kind, ClassKind)), None)
        # class slots: the dataset's declared classes plus `spare_classes` for classes added in the viewer (fixed by
        # the dataset, not by what the strokes file holds, so a checkpoint always fits the model built to load it)
        declared = int(metadata.get("declared_classes", len(self.class_names)))
        spare = self.config.spare_classes if self.class_spec is not None else 0
        self.num_classes = max(len(self.class_names), declared + spare)
        # world units per metre (the dataparser rescales poses); depth metrics are reported in metres
        self.dataparser_scale = float(metadata.get("dataparser_scale", 1.0))
        self.register_buffer("palette", semantic_palette(self.num_classes, metadata.get("semantic_colors")))
        # the viewer's legend and class picker, when the model renders classes (`viewer/`)
        self.semantic_classes = None if self.class_spec is None else SemanticViewerPanel(self.class_names, self.palette)

        balanced = [spec.name for spec in self.specs if spec is not self.rgb_spec]
        self.balancer: Optional[LossBalancer] = None
        if self.config.balancing.ratio is not None and balanced:
            self.balancer = LossBalancer(balanced, self.config.balancing.ratio)
        self.balance_now = False
        self.regularisers: Dict[str, Regulariser] = {
            name: config.setup() for name, config in self.config.regularisers.items()}
        self.sampling: RaySampling = build_sampling(self.config, self.specs, self.num_classes, self.scene_box.aabb)
        gather_hash_lookups(self.sampling)
        self.collider = NearFarCollider(near_plane=self.config.near_plane, far_plane=self.config.far_plane)
        self.renderer_depth = DepthRenderer(method="median")
        self.renderer_accumulation = AccumulationRenderer()

    @property
    def active_regularisers(self) -> Dict[str, Regulariser]:
        """The optional training terms that train this model."""
        return {name: term for name, term in self.regularisers.items() if term.active(self)}

    def get_param_groups(self) -> Dict[str, List[nn.Parameter]]:
        return self.sampling.param_groups()

    def get_training_callbacks(
        self, training_callback_attributes: TrainingCallbackAttributes
    ) -> List[TrainingCallback]:
        # asked once, before the first step: where the run's length is known (without a trainer it is not: eager)
        trainer = getattr(training_callback_attributes, "trainer", None)
        run_steps = 0 if trainer is None else trainer.config.max_num_iterations
        self.config.compile.apply(self.sampling, self.device, run_steps)
        callbacks = [
            TrainingCallback([TrainingCallbackLocation.BEFORE_TRAIN_ITERATION], self.sampling.before_training_step),
            TrainingCallback([TrainingCallbackLocation.AFTER_TRAIN_ITERATION], self.sampling.after_training_step),
        ]
        if self.balancer is not None:
            callbacks.append(TrainingCallback([TrainingCallbackLocation.BEFORE_TRAIN_ITERATION], self.schedule_balance))
        if self.config.encoder_init is not None:  # at step 0 only: a resumed run keeps its own trained weights
            callbacks.append(TrainingCallback([TrainingCallbackLocation.BEFORE_TRAIN_ITERATION], self.init_encoders,
                                              iters=(0,)))
        return callbacks

    def schedule_balance(self, step: int) -> None:
        """Ask the next loss computation to re-measure the balancing's gradient norms (every `balancing.every`)."""
        self.balance_now = step % self.config.balancing.every == 0

    def init_encoders(self, step: int) -> None:
        """Copy F_enc from `encoder_init` (knowledge transfer); the trainer calls it before step 0."""
        assert self.config.encoder_init is not None
        loaded = load_encoders(self, self.config.encoder_init)
        CONSOLE.print(f"F_enc ({', '.join(loaded)}) initialised from {self.config.encoder_init}")

    def _render_level(self, level: SampleLevel, context: RenderContext, prefix: str) -> Dict[str, Tensor]:
        """Render every property of one sample level into `prefix + prediction_key` outputs."""
        return {
            prefix + spec.prediction_key: spec.kind.render(level.field_outputs[spec.name], level.weights, context)
            for spec in self.specs
        }

    def get_outputs(self, ray_bundle: RayBundle) -> Dict[str, Tensor | List]:
        result: SamplingResult = self.sampling(ray_bundle)
        pose = (ray_bundle.metadata or {}).get(POSE_METADATA_KEY)
        rotation = None if pose is None else pose.view(*pose.shape[:-1], 3, 4)[..., :3]
        context = RenderContext(world_to_camera=None if rotation is None else rotation.transpose(-1, -2))
        outputs: Dict[str, Tensor | List] = {}
        for prefix, level in zip(self.level_prefixes, result.levels):
            outputs.update(self._render_level(level, context, prefix))
            if self.class_spec is not None and len(self.class_names) < self.num_classes:
                # spare class slots no class has been given yet are never predicted
                key = prefix + self.class_spec.prediction_key
                outputs[key] = outputs[key].masked_fill(self.unnamed_slots.to(outputs[key].device), UNNAMED_LOGIT)
        final = result.levels[-1]
        for spec in self.specs:
            if spec.prediction_key != spec.name:
                outputs[spec.name] = spec.display(outputs[spec.prediction_key], self.palette)
            if not self.training:  # (for the viewer, ns-render and the exporters, which all render in eval mode)
                outputs.update(spec.kind.export_outputs(spec.name, outputs[spec.prediction_key], context))
        shown = None if self.semantic_classes is None else self.semantic_classes.highlighted_class
        if self.class_spec is not None and shown is not None:
            outputs[self.class_spec.name] = highlight_class(
                outputs[self.class_spec.prediction_key], outputs[self.rgb_spec.prediction_key], self.palette, shown
            )
        outputs["depth"] = self.renderer_depth(weights=final.weights, ray_samples=final.ray_samples)
        outputs["accumulation"] = self.renderer_accumulation(weights=final.weights)
        if ray_bundle.metadata and "directions_norm" in ray_bundle.metadata:
            outputs["directions_norm"] = ray_bundle.metadata["directions_norm"]
        if self.training:
            if result.weights_list:
                outputs["weights_list"] = result.weights_list
                outputs["ray_samples_list"] = result.ray_samples_list
            for term in self.active_regularisers.values():
                outputs.update(term.outputs(self, result))
        return outputs

    def get_rgba_image(self, outputs: Dict[str, Tensor], output_name: str = "rgb") -> Tensor:
        """Any display output as RGBA for nerfstudio's exporters (`ns-export --rgb-output-name semantics` gives class
        colours, a scalar map its grey), with the accumulation as alpha so that rays through empty space drop out."""
        colours = outputs[output_name]
        colours = colours.expand(*colours.shape[:-1], 3) if colours.shape[-1] == 1 else colours[..., :3]
        return torch.cat([colours, outputs["accumulation"]], dim=-1)

    @property
    def unnamed_slots(self) -> Tensor:
        """(num_classes,) mask of the spare class slots that have no name yet (`class_names` grows in the viewer)."""
        return torch.arange(self.num_classes) >= len(self.class_names)

    @property
    def level_prefixes(self) -> List[str]:
        """Output prefixes of the supervised levels: "" for the final one, "level0_", ... for earlier ones."""
        return [f"level{index}_" for index in range(self.sampling.num_levels - 1)] + [""]

    @property
    def rgb_spec(self) -> PropertySpec:
        """RGB's spec (always trained; its label is nerfstudio's "image")."""
        return next(spec for spec in self.specs if spec.label_key == "image")

    def get_metrics_dict(self, outputs, batch) -> Dict[str, Tensor]:
        label = self.rgb_spec.label(batch, self.num_classes).to(self.device)
        valid = self.rgb_spec.kind.valid(label)  # (rays painted in the viewer have no colour)
        mse = torch.mean((outputs[self.rgb_spec.prediction_key][valid] - label[valid]) ** 2)
        metrics = {"psnr": -10.0 * torch.log10(mse)}
        if self.training and "weights_list" in outputs:
            metrics["distortion"] = distortion_loss(outputs["weights_list"], outputs["ray_samples_list"])
        if self.training and self.balancer is not None:
            metrics.update({f"{name}_loss_multiplier": self.balancer.multiplier(name) for name in self.balancer.names})
        return metrics

    def get_loss_dict(self, outputs, batch, metrics_dict=None) -> Dict[str, Tensor]:
        """The paper's weighted sum: every property on every supervised level, each logged as `<name>_loss`; then
        the proposal losses and each active regulariser's `<name>_loss`."""
        losses: Dict[str, Tensor] = {}
        for spec in self.specs:
            label = spec.label(batch, self.num_classes).to(self.device)
            valid = spec.kind.valid(label)
            for prefix in self.level_prefixes:
                prediction = outputs[prefix + spec.prediction_key]
                losses[f"{prefix}{spec.name}_loss"] = spec.weight * LOSSES[spec.loss](prediction, label, valid)
        if self.balancer is not None and self.training:
            encoders = [p for module in encoder_modules(self).values() for p in module.parameters()]
            self.balancer.scale(losses, self.rgb_spec.name, self.level_prefixes, encoders, measure=self.balance_now)
            self.balance_now = False
        if self.training and "weights_list" in outputs:
            losses["interlevel_loss"] = self.config.interlevel_loss_mult * interlevel_loss(
                outputs["weights_list"], outputs["ray_samples_list"]
            )
            assert metrics_dict is not None
            losses["distortion_loss"] = self.config.distortion_loss_mult * metrics_dict["distortion"]
        if self.training:
            for name, term in self.active_regularisers.items():
                loss = term.loss(self, outputs, batch)
                if loss is not None:
                    losses[f"{name}_loss"] = loss
        return losses

    @property
    def display_output_names(self) -> List[str]:
        """Outputs people look at: RGB and each property as a display image (and its kind's `display_extras`, e.g.
        the class uncertainty), depth and accumulation. The viewer's output list and `ns-render`'s names; logits, raw
        values and coarse levels stay internal."""
        return [name for spec in self.specs for name in (spec.name, *spec.kind.display_extras(spec.name))] + [
            "depth", "accumulation"]

    @torch.no_grad()
    def get_outputs_for_camera(self, camera: Cameras, obb_box=None) -> Dict[str, Tensor]:
        """The display outputs (`display_output_names`) of a full camera: what the viewer and `ns-render` call."""
        outputs = self.render_camera(camera, obb_box=obb_box)
        return {name: outputs[name] for name in self.display_output_names}

    @torch.no_grad()
    def render_camera(self, camera: Cameras, obb_box=None) -> Dict[str, Tensor]:
        """Every output of a full camera, predictions included (evaluation); its rays carry the camera pose (viewer
        and render cameras lack it)."""
        return super().get_outputs_for_camera(add_pose_metadata(camera), obb_box=obb_box)

    def get_image_statistics(self, outputs: Dict[str, Tensor], batch: Dict[str, Tensor]) -> Dict[str, Statistics]:
        """Each property's additive metric statistics on one image (and depth's, when the data has depth maps)."""
        statistics: Dict[str, Statistics] = {}
        for spec in self.specs:
            label = spec.label(batch, self.num_classes).to(self.device)
            metric = METRICS[spec.metric]
            prediction = outputs[spec.prediction_key]
            statistics[spec.name] = metric.statistics(prediction, label, spec.kind.valid(label), self.num_classes)
        if DEPTH_KEY in batch and "directions_norm" in outputs:
            truth = batch[DEPTH_KEY].to(self.device)
            z_depth = rendered_z_depth(outputs) / self.dataparser_scale
            valid = (torch.isfinite(truth) & (truth > 0))[..., 0]
            statistics[DEPTH_METRIC] = METRICS[DEPTH_METRIC].statistics(z_depth, truth, valid, self.num_classes)
        return statistics

    def metrics_from_statistics(self, statistics: Dict[str, Statistics]) -> Dict[str, float]:
        """Named metrics from statistics of one image or summed over a split (`metrics.summarize`)."""
        return summarize(statistics, self.specs)

    def get_image_metrics_and_images(
        self, outputs: Dict[str, Tensor], batch: Dict[str, Tensor]
    ) -> Tuple[Dict[str, float], Dict[str, Tensor]]:
        """Every property's metric on one image, and ground truth | prediction images for logging."""
        metrics = self.metrics_from_statistics(self.get_image_statistics(outputs, batch))
        images: Dict[str, Tensor] = {}
        for spec in self.specs:
            label = spec.label(batch, self.num_classes).to(self.device)
            shown_label = spec.display(spec.kind.label_as_prediction(label, self.num_classes), self.palette)
            images[spec.name] = torch.cat([shown_label, spec.display(outputs[spec.prediction_key], self.palette)], 1)
        images["depth"] = colormaps.apply_depth_colormap(outputs["depth"], accumulation=outputs["accumulation"])
        return metrics, images
