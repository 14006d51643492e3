"""The model's fields and sampling strategy, built from its config (an `SSNeRFModelConfig`)."""

from __future__ import annotations

from typing import Any, Sequence

from torch import Tensor, nn

from nerfstudio.field_components.spatial_distortions import SceneContraction
from nerfstudio.fields.density_fields import HashMLPDensityField

from ssnerf_method.fields.encoders import HashGridEncoder, PositionalMLPEncoder, PositionEncoder
from ssnerf_method.fields.ssnerf_field import SSNeRFField
from ssnerf_method.properties import PropertySpec
from ssnerf_method.rendering.sampling import HierarchicalSampling, ProposalSampling, RaySampling


def build_field(config: Any, specs: Sequence[PropertySpec], num_classes: int) -> SSNeRFField:
    """One SS-NeRF field: F_enc (`encoder`) and the decoders."""
    encoder: PositionEncoder
    if config.encoder == "hashgrid":
        encoder = HashGridEncoder(
            num_levels=config.grid_levels, max_res=config.grid_max_res,
            log2_hashmap_size=config.grid_log2_hashmap_size, hidden_dim=config.grid_hidden_dim,
            feature_dim=config.grid_feature_dim, implementation=config.implementation,
        )
    else:
        encoder = PositionalMLPEncoder(num_layers=config.encoder_layers, width=config.encoder_width)
    return SSNeRFField(
        specs, num_classes, encoder, direction_encoding=config.direction_encoding,
        decoder_width=config.decoder_width, decoder_layers=config.decoder_layers,
        decoder_sharing=config.decoder_sharing, density_activation=config.density_activation,
        density_noise=config.density_noise, implementation=config.implementation,
        class_grid_max_res=config.class_grid_max_res, class_grid_properties=config.class_grid_properties,
        class_grid_frequencies=config.class_grid_frequencies,
    )


def build_sampling(config: Any, specs: Sequence[PropertySpec], num_classes: int, aabb: Tensor) -> RaySampling:
    """The sampling strategy with its fields: hierarchical (coarse + fine, the paper's) or proposal (lite)."""
    if config.sampling == "hierarchical":
        coarse, fine = build_field(config, specs, num_classes), build_field(config, specs, num_classes)
        return HierarchicalSampling(coarse, fine, config.num_coarse_samples, config.num_fine_samples)
    contraction = SceneContraction(order=float("inf"))
    proposals = nn.ModuleList(
        HashMLPDensityField(
            aabb, spatial_distortion=contraction, num_levels=5, max_res=max_res,
            log2_hashmap_size=17, hidden_dim=16, implementation=config.implementation,
        )
        for max_res in config.proposal_max_res
    )
    return ProposalSampling(
        build_field(config, specs, num_classes), proposals, config.num_proposal_samples, config.num_field_samples,
        anneal_steps=config.proposal_weights_anneal_max_num_iters,
    )
