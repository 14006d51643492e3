"""SS-NeRF model: renders RGB and every enabled scene property from one shared field (paper Sec. 3.3).

Everything per property (heads, rendering, loss, metric, display) is read from the registry in
`ssnerf_method/properties.py`; this module only wires the field, the sampling strategy and nerfstudio's hooks.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Literal, Optional, Tuple, Type

import torch
import torch.nn.functional as F
from jaxtyping import Float
from torch import Tensor, nn

from nerfstudio.cameras.cameras import Cameras
from nerfstudio.cameras.rays import RayBundle
from nerfstudio.engine.callbacks import TrainingCallback, TrainingCallbackAttributes, TrainingCallbackLocation
from nerfstudio.field_components.encodings import HashEncoding
from nerfstudio.field_components.spatial_distortions import SceneContraction
from nerfstudio.fields.density_fields import HashMLPDensityField
from nerfstudio.model_components.losses import (
    DepthLossType,
    depth_loss,
    distortion_loss,
    interlevel_loss,
    orientation_loss,
    pred_normal_loss,
)
from nerfstudio.model_components.renderers import AccumulationRenderer, DepthRenderer
from nerfstudio.model_components.scene_colliders import NearFarCollider
from nerfstudio.models.base_model import Model, ModelConfig
from nerfstudio.utils import colormaps
from nerfstudio.utils.rich_utils import CONSOLE

from ssnerf_method.data.dataset import DEPTH_KEY
from ssnerf_method.data.pixel_sampler import PATCH_RAYS, SMOOTHNESS_PATCHES_KEY
from ssnerf_method.data.pose_metadata import POSE_METADATA_KEY, add_pose_metadata
from ssnerf_method.data.strokes import StrokeStore, WorldFrame
from ssnerf_method.fields.compiled import native_bfloat16
from ssnerf_method.fields.encoders import (
    HashGridEncoder,
    PositionalMLPEncoder,
    PositionEncoder,
    gather_hash_lookups,
)
from ssnerf_method.fields.ssnerf_field import DecoderSharing, SSNeRFField
from ssnerf_method.metrics import DEPTH_METRIC, METRICS, Statistics, summarize
from ssnerf_method.model.encoder_transfer import encoder_modules, load_encoders
from ssnerf_method.model.loss_balancing import LossBalancer
from ssnerf_method.model.losses import LOSSES, colour_affinity_loss, planar_smoothness_loss
from ssnerf_method.properties import (
    OPTIONAL_PROPERTIES,
    REGISTRY,
    UNNAMED_LOGIT,
    Branch,
    ClassKind,
    LossName,
    NormalKind,
    PropertySpec,
    RenderContext,
    class_property,
    resolve_properties,
)
from ssnerf_method.rendering.depth import rendered_z_depth
from ssnerf_method.rendering.palette import semantic_palette
from ssnerf_method.rendering.sampling import (
    HierarchicalSampling,
    ProposalSampling,
    RaySampling,
    SampleLevel,
    SamplingResult,
)
from ssnerf_method.viewer.label_panel import LabelPanel
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
    """"world": predict world-frame normals, render, normalise, rotate into the camera; "pose": the paper's
    camera-pose-conditioned F_dec^nv predicting the camera-frame encoding directly."""
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
    """If > 0, the decoders of `class_grid_properties` also see a coarse hash grid of their own (4 levels, resolution
    16 up to this one), spatially smooth, through which a few annotated frames, clicked pixels or viewer strokes spread
    to the surfaces around them (`ssnerf-study propagation`). 0: none (the paper's decoders)."""
    class_grid_frequencies: int = 0
    """If > 0, the class grid's features are followed by sinusoids of the position at this many octaves (the lowest
    one period across the contracted scene), a smooth input that carries a class beyond the labelled surfaces.
    0: the grid alone."""
    class_grid_properties: Tuple[str, ...] = CLASS_GRID_PROPERTIES
    """Properties whose decoder MLP sees the class grid (each has an MLP of its own), when `class_grid_max_res` > 0:
    the class-valued one by default; normals, shading and keypoints gain from it too (ssnerf-lite's)."""
    direction_encoding: Literal["nerf", "sh"] = "nerf"
    """View-direction encoding of F_dec^v: 4-frequency sinusoids (paper) or spherical harmonics."""
    decoder_width: int = 128
    """Width of each decoder branch."""
    decoder_layers: int = 1
    """Hidden layers of each decoder branch."""
    decoder_sharing: DecoderSharing = "branch"
    """"branch": one decoder MLP per branch shared by its properties (the paper's F_dec^v, F_dec^nv); "property": one
    MLP per property on its branch's inputs, so RGB and the properties never share hidden units; "rgb-apart": RGB's own
    MLP and one per branch shared by the other properties (fewer MLPs than "property" when several are trained)."""
    property_decoder_width: Optional[int] = None
    """Width of the decoder MLPs of the properties when they have their own ("property", "rgb-apart"); None:
    `decoder_width`. The per-property MLPs are most of what the properties add to a step's cost."""
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
    hash_lookup: Literal["gathered", "nerfstudio"] = "gathered"
    """Torch-path hash grids (the field's and the proposal networks'): "gathered" reads the eight cell corners in one
    batch (`fields/encoders.py`, the same features, a faster CPU step), "nerfstudio" keeps `HashEncoding`'s lookup."""
    compile_fields: bool = True
    """CPU training: run the field's and the proposal networks' training forwards and backwards through
    `torch.compile` (`fields/compiled.py`): the same outputs from a cheaper step, after a compile of tens of seconds at
    the first step (less once inductor's cache in the temp folder holds it). Only in runs of at least
    `compile_min_steps` steps; where compiling fails, one console line and eager steps. Evaluation, the viewer and
    CUDA training stay eager."""
    bfloat16_matmuls: bool = True
    """With `compile_fields`, on a CPU that multiplies bfloat16 in hardware (AMX or AVX512-BF16; elsewhere it is
    ignored): the compiled networks' matrix multiplications in bfloat16 (`torch.autocast`), as tiny-cuda-nn runs
    nerfstudio's MLPs in half precision on a GPU. Parameters, hash tables, rendering and losses stay float32."""
    compile_min_steps: int = 300
    """Runs of fewer training steps (the trainer's `max_num_iterations`) stay eager: the compile would not pay off."""
    balance_ratio: Optional[float] = None
    """Gradient-norm balancing (`model/loss_balancing.py`): if set, every `balance_every` steps each property's loss is
    scaled (by at most 1) so that its gradient into F_enc is at most this multiple of RGB's. None trains the paper's
    fixed weighted sum."""
    balance_every: int = 100
    """Steps between two measurements of the balancing's gradient norms (each costs one backward pass per loss)."""
    depth_loss_mult: float = 0.0
    """Weight of a depth loss on the rays whose frame has a depth map (`depth_file_path`): nerfstudio's depth-nerfacto
    loss (`depth_loss_type`), on every level's weights (the proposal networks' too). 0: depth is scored, never trained
    (the paper's, whose data has no depth)."""
    depth_loss_type: DepthLossType = DepthLossType.DS_NERF
    """Depth loss: DS-NeRF's (weights pulled into a narrow window around the true depth) or URF's."""
    depth_sigma: float = 0.01
    """Width of the depth loss's window around the true depth, in scene units (as nerfstudio's `depth_sigma`)."""
    depth_smoothness_mult: float = 0.0
    """If > 0, the weight of a loss that keeps flat surfaces flat where no depth is known: on
    `pixel_patches` 3x3 pixel patches of each batch, the second differences of the rendered inverse
    z-depth, which vanish on any plane, relative to the patch centre's and weighted down across colour edges
    (RegNeRF's depth smoothness, made planar). For a model whose depth makes normals (`ssnerf-label --depth-from`).
    0: off."""
    depth_smoothness_edge: float = 10.0
    """How fast the smoothness weight falls with the largest colour difference within a patch (RGB in [0, 1])."""
    semantic_affinity_mult: float = 1.0
    """If > 0, sparse class labels in the frames (clicks, scribbles, partly annotated frames; not the viewer's
    strokes, which are rays) spread over the image: on `pixel_patches` 3x3 pixel patches of each batch, a neighbour
    of like colour is pulled to the centre pixel's class probabilities (`colour_affinity_loss`, a dense CRF's
    pairwise term). Relative to the class loss (its weight and the gradient balancer's multiplier apply). Pairs of
    labelled pixels are left to their labels, and the sampler draws the patches only while the class labels are
    sparse and only from partly labelled frames: densely labelled data trains as without it."""
    semantic_affinity_edge: float = 10.0
    """How fast the affinity falls with the largest colour difference between two pixels (RGB in [0, 1])."""
    semantic_affinity_stride: int = 2
    """Pixels between neighbouring rays of the affinity's patches (with `depth_smoothness_mult` on too, the patches
    are the depth smoothness's: the sampler's `smoothness_patch_stride`)."""
    pixel_patches: int = 32
    """Patches per batch for `depth_smoothness_mult` and `semantic_affinity_mult` (9 rays each, in place of uniform
    rays; the pipeline hands the number to the pixel sampler's `smoothness_patches`)."""
    normals_density_mult: float = 0.0
    """If > 0, the weight of a loss that lets the normals labels shape the geometry: at each ray's
    `normals_density_samples` heaviest samples, the density's own normals (`SSNeRFField.density_normals`) are pulled
    towards the predicted normals (detached) and kept facing the camera (nerfstudio's `pred_normal_loss` and
    `orientation_loss`, as nerfacto and Ref-NeRF use them, but with the gradient into the density instead of the
    normals head). Only with world-frame normals trained (`normals_mode` world); otherwise nothing. 0: off."""
    normals_density_samples: int = 2
    """Samples per ray, the heaviest, at which `normals_density_mult`'s loss is computed (each costs three more
    F_enc evaluations)."""
    normals_density_step: float = 0.01
    """Finite-difference step of the density's normals, in scene units (the density is smoothed over it)."""
    spare_classes: int = 0
    """Semantic class slots beyond the dataset's classes, for classes added in the viewer's Label panel while
    training (a new class takes the next free slot). 0: classes can only come from the dataset."""
    encoder_init: Optional[Path] = None
    """Checkpoint (.ckpt) of a trained SS-NeRF of the same method whose F_enc initialises this one's at the first step;
    decoders, heads and proposal networks start fresh (the paper's knowledge transfer, Table 5)."""


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
            [name for name in self.config.properties if name in available],
            branches=self.config.branches,
            weights=self.config.loss_weights,
            normals_mode=self.config.normals_mode,
            losses=self.config.losses,
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
        # the viewer's legend and class picker, when the model renders classes
        self.semantic_classes = None if self.class_spec is None else SemanticViewerPanel(self.class_names, self.palette)

        balanced = [spec.name for spec in self.specs if spec is not self.rgb_spec]
        self.balancer: Optional[LossBalancer] = None
        if self.config.balance_ratio is not None and balanced:
            self.balancer = LossBalancer(balanced, self.config.balance_ratio)
        self.balance_now = False
        self.sampling: RaySampling = self._build_sampling()
        if self.config.hash_lookup == "gathered":
            gather_hash_lookups(self.sampling)
        self.collider = NearFarCollider(near_plane=self.config.near_plane, far_plane=self.config.far_plane)
        self.renderer_depth = DepthRenderer(method="median")
        self.renderer_expected_depth = DepthRenderer(method="expected")  # differentiable, for the depth smoothness
        self.renderer_accumulation = AccumulationRenderer()

    def add_label_panel(self, store: StrokeStore, frame: WorldFrame, image_height: int, training: bool) -> None:
        """The viewer's Label panel under the semantics panel (`viewer/label_panel.py`), when the model renders
        classes: strokes painted there go to `store`; a class added there joins `class_names` and "Show class"."""
        if self.class_spec is None or self.semantic_classes is None:
            return
        panel = self.semantic_classes

        def new_class(names: List[str]) -> None:
            self.class_names = names
            panel.set_classes(names)

        self.semantic_labelling = LabelPanel(store, frame, self.class_names, self.num_classes, self.palette,
                                             image_height, training, on_new_class=new_class)

    def _build_field(self) -> SSNeRFField:
        encoder: PositionEncoder
        if self.config.encoder == "hashgrid":
            encoder = HashGridEncoder(
                num_levels=self.config.grid_levels, max_res=self.config.grid_max_res,
                log2_hashmap_size=self.config.grid_log2_hashmap_size, hidden_dim=self.config.grid_hidden_dim,
                feature_dim=self.config.grid_feature_dim, implementation=self.config.implementation,
            )
        else:
            encoder = PositionalMLPEncoder(num_layers=self.config.encoder_layers, width=self.config.encoder_width)
        return SSNeRFField(
            self.specs, self.num_classes, encoder,
            direction_encoding=self.config.direction_encoding,
            decoder_width=self.config.decoder_width,
            decoder_layers=self.config.decoder_layers,
            decoder_sharing=self.config.decoder_sharing,
            property_decoder_width=self.config.property_decoder_width,
            density_activation=self.config.density_activation,
            density_noise=self.config.density_noise,
            implementation=self.config.implementation,
            class_grid=self._build_class_grid(),
            class_grid_properties=self.config.class_grid_properties,
            class_grid_frequencies=self.config.class_grid_frequencies,
        )

    def _build_class_grid(self) -> Optional[HashEncoding]:
        """The class grid of `class_grid_max_res` (None when 0, or when none of `class_grid_properties` is trained)."""
        unknown = sorted(set(self.config.class_grid_properties) - set(REGISTRY))
        if unknown:
            raise ValueError(f"class_grid_properties: {', '.join(unknown)} is not a property; choose among "
                             f"{', '.join(REGISTRY)}")
        trained = {spec.name for spec in self.specs}
        if self.config.class_grid_max_res <= 0 or not trained & set(self.config.class_grid_properties):
            return None
        return HashEncoding(num_levels=4, min_res=16, max_res=self.config.class_grid_max_res, log2_hashmap_size=17,
                            features_per_level=2, implementation=self.config.implementation)

    def _build_sampling(self) -> RaySampling:
        if self.config.sampling == "hierarchical":
            return HierarchicalSampling(
                self._build_field(), self._build_field(), self.config.num_coarse_samples, self.config.num_fine_samples
            )
        contraction = SceneContraction(order=float("inf"))
        proposals = nn.ModuleList(
            HashMLPDensityField(
                self.scene_box.aabb, spatial_distortion=contraction, num_levels=5, max_res=max_res,
                log2_hashmap_size=17, hidden_dim=16, implementation=self.config.implementation,
            )
            for max_res in self.config.proposal_max_res
        )
        return ProposalSampling(
            self._build_field(), proposals, self.config.num_proposal_samples, self.config.num_field_samples,
            anneal_steps=self.config.proposal_weights_anneal_max_num_iters,
        )

    def get_param_groups(self) -> Dict[str, List[nn.Parameter]]:
        return self.sampling.param_groups()

    def get_training_callbacks(
        self, training_callback_attributes: TrainingCallbackAttributes
    ) -> List[TrainingCallback]:
        # asked once, before the first step: where the run's length is known (without a trainer it is not: eager)
        trainer = getattr(training_callback_attributes, "trainer", None)
        run_steps = 0 if trainer is None else trainer.config.max_num_iterations
        if self.config.compile_fields and self.device.type == "cpu" and run_steps >= self.config.compile_min_steps:
            self.sampling.compile_for_training(self.config.bfloat16_matmuls and native_bfloat16())
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
        """Ask the next loss computation to re-measure the balancing's gradient norms (every `balance_every` steps)."""
        self.balance_now = step % self.config.balance_every == 0

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
        if self.training and self.config.normals_density_mult > 0 and self.density_normal_spec is not None:
            outputs["normals_density"] = self.normals_density(final, ray_bundle.directions)
        outputs["depth"] = self.renderer_depth(weights=final.weights, ray_samples=final.ray_samples)
        outputs["accumulation"] = self.renderer_accumulation(weights=final.weights)
        if ray_bundle.metadata and "directions_norm" in ray_bundle.metadata:
            outputs["directions_norm"] = ray_bundle.metadata["directions_norm"]
        if self.training and result.weights_list:
            outputs["weights_list"] = result.weights_list
            outputs["ray_samples_list"] = result.ray_samples_list
        if self.training and self.config.depth_smoothness_mult > 0:
            outputs["expected_depth"] = self.renderer_expected_depth(weights=final.weights,
                                                                     ray_samples=final.ray_samples)
        if self.training and self.config.depth_loss_mult > 0:  # every level's weights, proposals included
            levels = result.levels
            outputs["depth_weights_list"] = result.weights_list or [level.weights for level in levels]
            outputs["depth_ray_samples_list"] = result.ray_samples_list or [level.ray_samples for level in levels]
        return outputs

    @property
    def density_normal_spec(self) -> Optional[PropertySpec]:
        """The trained world-frame normals, which `normals_density_mult` ties the density's normals to (if any)."""
        return next((spec for spec in self.specs if isinstance(spec.kind, NormalKind) and spec.kind.mode == "world"),
                    None)

    def normals_density(self, level: SampleLevel, directions: Float[Tensor, "*bs 3"]) -> Float[Tensor, ""]:
        """`normals_density_mult`'s loss on one level: the density's normals against the predicted ones at each ray's
        heaviest samples, plus their orientation towards the camera, weighted by the samples' (detached) weights."""
        spec = self.density_normal_spec
        assert spec is not None
        weights = level.weights.detach()
        count = min(self.config.normals_density_samples, weights.shape[-2])
        heaviest = weights[..., 0].topk(count, dim=-1).indices[..., None]  # (*bs, count, 1)

        def pick(values: Tensor) -> Tensor:
            return values.gather(-2, heaviest.expand(*heaviest.shape[:-1], values.shape[-1]))

        positions = pick(level.ray_samples.frustums.get_positions())
        density_normals = self.sampling.final_field.density_normals(positions, self.config.normals_density_step)
        predicted = F.normalize(pick(level.field_outputs[spec.name]).detach().float(), dim=-1)
        picked = pick(weights)
        loss = pred_normal_loss(picked, density_normals, predicted) + orientation_loss(picked, density_normals,
                                                                                       directions)
        return loss.mean()

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
        """The paper's weighted sum: every property on every supervised level, each logged as `<name>_loss`."""
        losses: Dict[str, Tensor] = {}
        for spec in self.specs:
            label = spec.label(batch, self.num_classes).to(self.device)
            valid = spec.kind.valid(label)
            for prefix in self.level_prefixes:
                prediction = outputs[prefix + spec.prediction_key]
                losses[f"{prefix}{spec.name}_loss"] = spec.weight * LOSSES[spec.loss](prediction, label, valid)
        if self.balancer is not None and self.training:
            if self.balance_now:
                self.balance_now = False
                encoders = [p for module in encoder_modules(self).values() for p in module.parameters()]
                finals = {name: losses[f"{name}_loss"] for name in self.balancer.names}
                self.balancer.update(losses[f"{self.rgb_spec.name}_loss"], finals, encoders)
            for name in self.balancer.names:
                for prefix in self.level_prefixes:
                    losses[f"{prefix}{name}_loss"] = losses[f"{prefix}{name}_loss"] * self.balancer.multiplier(name)
        if self.training and "weights_list" in outputs:
            losses["interlevel_loss"] = self.config.interlevel_loss_mult * interlevel_loss(
                outputs["weights_list"], outputs["ray_samples_list"]
            )
            assert metrics_dict is not None
            losses["distortion_loss"] = self.config.distortion_loss_mult * metrics_dict["distortion"]
        if "normals_density" in outputs:
            losses["normals_density_loss"] = self.config.normals_density_mult * outputs["normals_density"]
        if self.training and "depth_weights_list" in outputs and DEPTH_KEY in batch:
            losses["depth_loss"] = self.config.depth_loss_mult * self.depth_loss(outputs, batch)
        patches = int(batch.get(SMOOTHNESS_PATCHES_KEY, 0)) if self.training else 0
        if patches > 0 and self.config.depth_smoothness_mult > 0:
            losses["depth_smoothness_loss"] = self.config.depth_smoothness_mult * self.depth_smoothness(
                outputs, batch, patches)
        if patches > 0 and self.config.semantic_affinity_mult > 0 and self.class_spec is not None:
            losses["semantic_affinity_loss"] = self.config.semantic_affinity_mult * self.class_spec.weight * (
                self.balancer.multiplier(self.class_spec.name) if self.balancer is not None else 1.0
            ) * self.semantic_affinity(outputs, batch, patches)
        return losses

    def patch_colours(self, batch: Dict[str, Tensor], patches: int) -> Tensor:
        """(patches, 9, 3) colours of the batch's first `patches` 3x3 pixel patches, which both patch losses weigh
        by."""
        colours = self.rgb_spec.label(batch, self.num_classes).to(self.device)[: patches * PATCH_RAYS]
        return colours.view(patches, PATCH_RAYS, -1)

    def semantic_affinity(self, outputs: Dict[str, Tensor | List], batch: Dict[str, Tensor], patches: int) -> Tensor:
        """`semantic_affinity_mult`'s loss (`colour_affinity_loss`) on the batch's first `patches` 3x3 patches."""
        assert self.class_spec is not None
        rays = patches * PATCH_RAYS
        logits = outputs[self.class_spec.prediction_key][:rays]
        probabilities = torch.softmax(logits.float(), dim=-1).view(patches, PATCH_RAYS, -1)
        label = self.class_spec.label(batch, self.num_classes).to(self.device)[:rays]
        labelled = self.class_spec.kind.valid(label).view(patches, PATCH_RAYS)
        return colour_affinity_loss(probabilities, self.patch_colours(batch, patches), labelled,
                                    self.config.semantic_affinity_edge)

    def depth_smoothness(self, outputs: Dict[str, Tensor | List], batch: Dict[str, Tensor], patches: int) -> Tensor:
        """`depth_smoothness_mult`'s loss (`planar_smoothness_loss`) on the batch's first `patches` 3x3 patches, from
        the field's expected depth (differentiable, unlike the rendered median)."""
        rays = patches * PATCH_RAYS
        distance = outputs["expected_depth"][:rays]
        norm = outputs["directions_norm"][:rays] if "directions_norm" in outputs else torch.ones_like(distance)
        inverse = (norm / distance.clamp_min(1e-3)).view(patches, 3, 3)
        return planar_smoothness_loss(inverse, self.patch_colours(batch, patches), self.config.depth_smoothness_edge)

    def depth_loss(self, outputs: Dict[str, Tensor | List], batch: Dict[str, Tensor]) -> Tensor:
        """nerfstudio's depth loss against the frames' z-depth maps, averaged over the levels (as depth-nerfacto).
        Pixels without depth (0) carry none."""
        truth = batch[DEPTH_KEY].to(self.device) * self.dataparser_scale
        truth = torch.where(torch.isfinite(truth), truth, torch.zeros_like(truth))
        levels = list(zip(outputs["depth_weights_list"], outputs["depth_ray_samples_list"]))
        sigma = torch.tensor([self.config.depth_sigma], device=self.device)
        return sum(
            depth_loss(weights=weights, ray_samples=ray_samples, termination_depth=truth,
                       predicted_depth=outputs["depth"], sigma=sigma, directions_norm=outputs["directions_norm"],
                       is_euclidean=False, depth_loss_type=self.config.depth_loss_type)
            for weights, ray_samples in levels
        ) / len(levels)

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
