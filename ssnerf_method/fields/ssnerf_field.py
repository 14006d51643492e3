"""The SS-NeRF field: F_enc gives density and a feature, F_dec^v and F_dec^nv turn the feature into properties.

Which decoder predicts which property comes from each `PropertySpec.branch` (the paper's Table 3 swaps them). The
view-dependent decoder also sees the encoded view direction; the view-independent one optionally sees the encoded
camera pose (the paper's surface-normal modelling). Optionally, the decoder MLPs of some properties (semantics; in
`ssnerf-lite` also normals, shading and keypoints) see a coarse grid of their own (`class_grid`), through which sparse
labels spread.
"""

from __future__ import annotations

from typing import Dict, List, Literal, Optional, Sequence, Tuple

import torch
from jaxtyping import Float
from torch import Tensor, nn

from nerfstudio.cameras.rays import RaySamples
from nerfstudio.field_components.activations import trunc_exp
from nerfstudio.field_components.encodings import HashEncoding, NeRFEncoding, SHEncoding
from nerfstudio.field_components.field_heads import FieldHeadNames
from nerfstudio.field_components.mlp import MLP
from nerfstudio.field_components.spatial_distortions import SceneContraction
from nerfstudio.fields.base_field import Field, get_normalized_directions

from ssnerf_method.data.pose_metadata import POSE_METADATA_KEY
from ssnerf_method.fields.compiled import CompiledOrEager
from ssnerf_method.fields.encoders import PositionEncoder, unit_cube
from ssnerf_method.properties import REGISTRY, Branch, PropertySpec


class BranchDecoder(nn.Module):
    """One decoder branch: a small MLP over its inputs, then one linear head per property (fused into one layer)."""

    def __init__(self, in_dim: int, width: int, num_layers: int, head_channels: Dict[str, int]) -> None:
        super().__init__()
        self.names = list(head_channels)
        self.channels = [head_channels[name] for name in self.names]
        self.mlp = MLP(in_dim=in_dim, num_layers=num_layers, layer_width=width, out_dim=width,
                       activation=nn.ReLU(), out_activation=nn.ReLU())
        self.heads = nn.Linear(width, sum(self.channels))

    def forward(self, inputs: Float[Tensor, "*bs in_dim"]) -> Dict[str, Tensor]:
        raw = self.heads(self.mlp(inputs))
        return dict(zip(self.names, torch.split(raw, self.channels, dim=-1)))


class GroupedDecoders(nn.Module):
    """A decoder branch split into several MLPs on the same inputs, each giving a group of the branch's properties:
    properties in different groups (RGB included) never compete for hidden units. The groups named in `extended`
    also see the first `extended[key]` extra inputs (the class grid's features, then its sinusoids) after the
    branch's."""

    def __init__(
        self, in_dim: int, width: int, num_layers: int, groups: Dict[str, Dict[str, int]],
        extended: Optional[Dict[str, int]] = None,
    ) -> None:
        super().__init__()
        self.names = [name for heads in groups.values() for name in heads]
        """The branch's properties, as `BranchDecoder.names`."""
        self.extended = {key: dim for key, dim in (extended or {}).items() if groups.get(key)}
        self.decoders = nn.ModuleDict({
            key: BranchDecoder(in_dim + self.extended.get(key, 0), width, num_layers, heads)
            for key, heads in groups.items() if heads
        })

    def forward(
        self, inputs: Float[Tensor, "*bs in_dim"], extra: Optional[Float[Tensor, "*bs extra_dim"]] = None
    ) -> Dict[str, Tensor]:
        outputs: Dict[str, Tensor] = {}
        for key, decoder in self.decoders.items():
            dim = self.extended.get(key, 0)
            wide = extra is not None and dim > 0
            outputs.update(decoder(torch.cat([inputs, extra[..., :dim]], dim=-1) if wide else inputs))  # type: ignore[index]
        return outputs


DecoderSharing = Literal["branch", "property"]
"""How a decoder branch's properties share MLPs. `branch`: one MLP per branch, shared by its properties (the paper's
F_dec^v and F_dec^nv); `property`: one MLP per property, keyed by its name."""


class SSNeRFField(Field):
    """Shared encoder plus the two property decoders.

    Args:
        specs: the properties this field predicts (RGB included).
        num_classes: number of semantic classes (head width of class-valued properties).
        encoder: the shared position encoder F_enc.
        direction_encoding: "nerf" (4-frequency sinusoids, the paper's) or "sh" (spherical harmonics, degree 4).
        decoder_width, decoder_layers: size of each decoder MLP.
        decoder_sharing: one decoder MLP per branch (the paper's) or one per property (`DecoderSharing`).
        density_activation: "relu" (NeRF) or "trunc_exp" (grid encoders, as in nerfacto).
        density_noise: std of Gaussian noise on raw density while training (NeRF regulariser; 0 disables).
        implementation: "tcnn" or "torch" for the spherical-harmonics encoding.
        class_grid_max_res: if > 0, the finest resolution of a coarse hash grid over contracted positions (mapped
            to [0, 1]; 4 levels from 16) whose features the decoder MLPs of `class_grid_properties` see beside e_x:
            spatially smooth, it spreads a few labelled pixels to the surfaces around them (e_x is sharp: alone,
            sparse labels stay where they are) and keeps what is constant over a surface (its normal) from e_x's
            fine-scale noise. 0: the paper's decoders.
        class_grid_properties: the properties whose decoder sees `class_grid` (each gets an MLP of its own).
        class_grid_frequencies: if > 0, the decoder of a class-valued property in `class_grid_properties` also sees
            sinusoids of the class grid's positions at this many octaves (the lowest one period across [0, 1]): a
            hash grid is blank where no label reached it, the sinusoids are a smooth function of position
            everywhere, so that a class labelled on part of a wall or a floor carries on along it. They have no
            parameters (checkpoints keep their names).
    """

    def __init__(
        self,
        specs: Sequence[PropertySpec],
        num_classes: int,
        encoder: PositionEncoder,
        direction_encoding: Literal["nerf", "sh"] = "nerf",
        decoder_width: int = 128,
        decoder_layers: int = 1,
        decoder_sharing: DecoderSharing = "branch",
        density_activation: Literal["relu", "trunc_exp"] = "relu",
        density_noise: float = 0.0,
        implementation: Literal["tcnn", "torch"] = "torch",
        class_grid_max_res: int = 0,
        class_grid_properties: Sequence[str] = (),
        class_grid_frequencies: int = 0,
    ) -> None:
        super().__init__()
        self.specs = {spec.name: spec for spec in specs}
        self.encoder = encoder
        unknown = sorted(set(class_grid_properties) - set(REGISTRY))
        if unknown:
            raise ValueError(f"class_grid_properties: {', '.join(unknown)} is not a property; choose among "
                             f"{', '.join(REGISTRY)}")
        gridded = {spec.name for spec in specs if class_grid_max_res > 0 and spec.name in class_grid_properties}
        self.class_grid: Optional[HashEncoding] = None
        if gridded:
            self.class_grid = HashEncoding(num_levels=4, min_res=16, max_res=class_grid_max_res, log2_hashmap_size=17,
                                           features_per_level=2, implementation=implementation)
        grid_dim = self.class_grid.get_out_dim() if self.class_grid is not None else 0  # type: ignore[operator]
        self.class_sinusoids: Optional[NeRFEncoding] = None
        if self.class_grid is not None and class_grid_frequencies > 0:
            self.class_sinusoids = NeRFEncoding(in_dim=3, num_frequencies=class_grid_frequencies, min_freq_exp=0.0,
                                                max_freq_exp=float(class_grid_frequencies - 1), include_input=True)
        sinusoid_dim = self.class_sinusoids.get_out_dim() if self.class_sinusoids is not None else 0
        extra_dims = {name: grid_dim + (sinusoid_dim if self.specs[name].kind.categorical else 0) for name in gridded}
        """Per property that sees the class grid: how many extra inputs it reads (the grid's, and the sinusoids for
        a class-valued one)."""
        self.spatial_distortion = SceneContraction(order=float("inf"))
        self.density_activation = density_activation
        self.density_noise = density_noise
        if direction_encoding == "sh":
            self.direction_encoding: nn.Module = SHEncoding(levels=4, implementation=implementation)
        else:
            self.direction_encoding = NeRFEncoding(in_dim=3, num_frequencies=4, min_freq_exp=0.0, max_freq_exp=3.0,
                                                   include_input=True)
        self.pose_encoding: Optional[NeRFEncoding] = None
        if any(spec.kind.needs_pose for spec in specs):  # the paper's normal modelling: F_dec^nv sees the pose
            self.pose_encoding = NeRFEncoding(in_dim=12, num_frequencies=10, min_freq_exp=0.0, max_freq_exp=9.0,
                                              include_input=True)

        branch_inputs = {
            "v": encoder.feature_dim + self.direction_encoding.get_out_dim(),
            "nv": encoder.feature_dim + (self.pose_encoding.get_out_dim() if self.pose_encoding is not None else 0),
        }
        self.decoders = nn.ModuleDict()
        for branch, in_dim in branch_inputs.items():
            heads = {spec.name: spec.kind.head_channels(num_classes) for spec in specs if spec.branch == branch}
            if not heads:
                continue
            groups = {name: {name: channels} for name, channels in heads.items()} if decoder_sharing == "property" \
                else None
            apart = [name for name in heads if name in gridded] if grid_dim else []
            if groups is None and not apart:
                self.decoders[branch] = BranchDecoder(in_dim, decoder_width, decoder_layers, heads)
                continue
            groups = groups or {branch: heads}  # `branch`: one shared MLP, keyed by the branch
            if apart:  # with a class grid, each property that sees it has an MLP of its own, the only one to see it
                shared = {key: {name: channels for name, channels in group.items() if name not in apart}
                          for key, group in groups.items()}
                groups = {**shared, **{name: {name: heads[name]} for name in apart}}
            self.decoders[branch] = GroupedDecoders(in_dim, decoder_width, decoder_layers, groups,
                                                    {name: extra_dims[name] for name in apart})

    def density_at(
        self, positions: Float[Tensor, "*bs 3"]
    ) -> Tuple[Float[Tensor, "*bs 1"], Float[Tensor, "*bs feature"]]:
        """Density and the shared feature e_x at world positions (F_enc after the scene contraction)."""
        raw_density, feature = self.encode(positions)
        return self.activate_density(raw_density), feature

    def encode(
        self, positions: Float[Tensor, "*bs 3"]
    ) -> Tuple[Float[Tensor, "*bs 1"], Float[Tensor, "*bs feature"]]:
        """F_enc's raw density and e_x at world positions; with a class grid, its features follow e_x in the same
        tensor (nerfstudio's `Field` hands one density embedding from `get_density` to `get_outputs`)."""
        contracted = self.spatial_distortion(positions)
        raw_density, feature = self.encoder(contracted)
        if self.class_grid is None:
            return raw_density, feature
        cube = unit_cube(contracted).reshape(-1, 3)
        grid = self.class_grid(cube)
        if self.class_sinusoids is not None:
            grid = torch.cat([grid, self.class_sinusoids(cube).to(grid)], dim=-1)
        return raw_density, torch.cat([feature, grid.view(*feature.shape[:-1], -1).to(feature)], dim=-1)

    def activate_density(self, raw_density: Float[Tensor, "*bs 1"]) -> Float[Tensor, "*bs 1"]:
        """Density from F_enc's raw output: the training noise (NeRF's regulariser), then the activation."""
        if self.training and self.density_noise > 0:
            raw_density = raw_density + torch.randn_like(raw_density) * self.density_noise
        if self.density_activation == "trunc_exp":
            return trunc_exp(raw_density)
        return torch.relu(raw_density)

    def get_density(self, ray_samples: RaySamples) -> Tuple[Float[Tensor, "*bs 1"], Float[Tensor, "*bs feature"]]:
        return self.density_at(ray_samples.frustums.get_positions())

    def sample_pose(self, ray_samples: RaySamples, feature: Tensor) -> Optional[Tensor]:
        """Each sample's flattened camera pose when F_dec^nv is pose-conditioned (the identity for rays without a
        camera, e.g. nerfstudio's exporter probes), else None."""
        if self.pose_encoding is None:
            return None
        if ray_samples.metadata is not None and POSE_METADATA_KEY in ray_samples.metadata:
            return ray_samples.metadata[POSE_METADATA_KEY]
        return torch.eye(4, device=feature.device)[:3].reshape(12).expand(*feature.shape[:-1], 12)

    def decoder_inputs(
        self, branch: Branch, feature: Tensor, directions: Tensor, pose: Optional[Tensor]
    ) -> Float[Tensor, "*bs in_dim"]:
        """The decoder input of one branch: the shared feature plus what that branch is conditioned on (the view
        direction for `v`, the encoded pose for a pose-conditioned `nv`)."""
        inputs: List[Tensor] = [feature]
        if branch == "v":
            if getattr(self.direction_encoding, "tcnn_encoding", None) is not None:
                # tcnn's SH takes [0, 1]; the torch path unit vectors
                directions = get_normalized_directions(directions)
            inputs.append(self.direction_encoding(directions))
        elif self.pose_encoding is not None and pose is not None:
            inputs.append(self.pose_encoding(pose).expand(*feature.shape[:-1], -1))
        return torch.cat(inputs, dim=-1)

    def branch_inputs(self, branch: Branch, ray_samples: RaySamples, feature: Tensor) -> Tensor:
        """`decoder_inputs` of samples."""
        return self.decoder_inputs(branch, feature, ray_samples.frustums.directions,
                                   self.sample_pose(ray_samples, feature))

    def outputs_from_feature(self, feature: Tensor, directions: Tensor, pose: Optional[Tensor]) -> Dict[str, Tensor]:
        """Each property's activated decoder output, by name (`feature`: e_x, then the class grid's features if any)."""
        grid: Optional[Tensor] = None
        if self.class_grid is not None:
            feature, grid = feature[..., :self.encoder.feature_dim], feature[..., self.encoder.feature_dim:]
        outputs: Dict[str, Tensor] = {}
        for branch, decoder in self.decoders.items():
            inputs = self.decoder_inputs(branch, feature, directions, pose)
            raw = decoder(inputs, grid) if isinstance(decoder, GroupedDecoders) else decoder(inputs)
            for name, values in raw.items():
                outputs[name] = self.specs[name].kind.activation(values)
        return outputs

    def get_outputs(
        self, ray_samples: RaySamples, density_embedding: Optional[Tensor] = None
    ) -> Dict[FieldHeadNames | str, Tensor]:
        assert density_embedding is not None
        pose = self.sample_pose(ray_samples, density_embedding)
        return dict(self.outputs_from_feature(density_embedding, ray_samples.frustums.directions, pose))

    def evaluate(
        self, positions: Float[Tensor, "num 3"], directions: Float[Tensor, "num 3"], pose: Optional[Tensor]
    ) -> Tuple[Float[Tensor, "num 1"], Dict[str, Tensor]]:
        """F_enc's raw density and every property at samples given as tensors: the field as one function of tensors
        (what `compile_for_training` compiles). The density's noise and activation stay outside, so that the noise
        comes from torch's generator as in eager steps (inductor draws its own random numbers)."""
        raw_density, feature = self.encode(positions)
        return raw_density, self.outputs_from_feature(feature, directions, pose)

    def compile_for_training(self, bfloat16_matmuls: bool = False) -> None:
        """Run training forwards through `torch.compile` (`fields/compiled.py`), with the matrix multiplications in
        bfloat16 if asked; evaluation stays eager, so viewer and render chunks of any size never wait for a compile.
        Parameters and state-dict keys are unchanged."""
        self.compiled_evaluate = CompiledOrEager(self.evaluate, "the SS-NeRF field", bfloat16_matmuls)

    def forward(self, ray_samples: RaySamples, compute_normals: bool = False) -> Dict[FieldHeadNames | str, Tensor]:
        compiled = getattr(self, "compiled_evaluate", None)
        if compiled is None or compute_normals or not self.training:
            return super().forward(ray_samples, compute_normals=compute_normals)
        positions = ray_samples.frustums.get_positions()
        pose = self.sample_pose(ray_samples, positions)
        batch = positions.shape[:-1]
        # one flat batch of samples: inductor lays out a flat batch's matmuls and activations far better than a
        # (rays, samples) one (measured: the compiled field was slower than eager on the latter)
        raw_density, outputs = compiled(positions.reshape(-1, 3), ray_samples.frustums.directions.reshape(-1, 3),
                                        None if pose is None else pose.expand(*batch, -1).reshape(-1, pose.shape[-1]))
        field_outputs: Dict[FieldHeadNames | str, Tensor] = {
            name: values.view(*batch, values.shape[-1]) for name, values in outputs.items()
        }
        field_outputs[FieldHeadNames.DENSITY] = self.activate_density(raw_density.view(*batch, 1))
        return field_outputs
