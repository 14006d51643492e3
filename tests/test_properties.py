"""The property registry against the field and the renderers: every subset of the optional properties, both branch
assignments, pose conditioning, and the paper's per-property choices."""

from __future__ import annotations

import itertools
from typing import Dict, List, Optional, Sequence

import pytest
import torch
from PIL import Image

from nerfstudio.cameras.rays import RayBundle, RaySamples
from nerfstudio.field_components.field_heads import FieldHeadNames
from nerfstudio.model_components.ray_samplers import UniformSampler

from ssnerf_method.data.pose_metadata import POSE_METADATA_KEY
from ssnerf_method.fields.encoders import HashGridEncoder, PositionalMLPEncoder
from ssnerf_method.fields.ssnerf_field import SSNeRFField
from ssnerf_method.metrics import METRICS
from ssnerf_method.model.losses import LOSSES
from ssnerf_method.properties import (
    OPTIONAL_PROPERTIES,
    REGISTRY,
    ColorKind,
    NormalKind,
    PropertySpec,
    RenderContext,
    ScalarKind,
    resolve_properties,
)
from ssnerf_method.rendering.weights import volume_weights

NUM_CLASSES = 4
NUM_RAYS = 5
NUM_SAMPLES = 6
SUBSETS = [subset for size in range(len(OPTIONAL_PROPERTIES) + 1)
           for subset in itertools.combinations(OPTIONAL_PROPERTIES, size)]


def _rotation_z(angle: float) -> torch.Tensor:
    c, s = float(torch.cos(torch.tensor(angle))), float(torch.sin(torch.tensor(angle)))
    return torch.tensor([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def make_bundle(
    num_rays: int = NUM_RAYS, pose: bool = True, seed: int = 0, rotation: Optional[torch.Tensor] = None,
    directions: Optional[torch.Tensor] = None,
) -> RayBundle:
    generator = torch.Generator().manual_seed(seed)
    if directions is None:
        directions = torch.nn.functional.normalize(torch.randn(num_rays, 3, generator=generator), dim=-1)
    rotation = torch.eye(3) if rotation is None else rotation
    c2w = torch.cat([rotation, torch.tensor([[0.1], [0.2], [0.3]])], dim=-1)
    metadata = {POSE_METADATA_KEY: c2w.reshape(1, 12).expand(num_rays, 12).clone()} if pose else {}
    return RayBundle(
        origins=torch.full((num_rays, 3), 0.1),
        directions=directions,
        pixel_area=torch.ones(num_rays, 1),
        camera_indices=torch.zeros(num_rays, 1, dtype=torch.long),
        nears=torch.full((num_rays, 1), 0.05),
        fars=torch.full((num_rays, 1), 2.0),
        metadata=metadata,
    )


def make_samples(bundle: RayBundle) -> RaySamples:
    return UniformSampler(num_samples=NUM_SAMPLES, train_stratified=False)(bundle)


def make_field(specs: Sequence[PropertySpec], encoder: str = "hashgrid") -> SSNeRFField:
    torch.manual_seed(0)
    if encoder == "hashgrid":
        enc = HashGridEncoder(num_levels=2, base_res=4, max_res=16, log2_hashmap_size=8, hidden_dim=16, feature_dim=8)
    else:
        enc = PositionalMLPEncoder(num_layers=2, width=32)
    field = SSNeRFField(specs, NUM_CLASSES, enc, decoder_width=16)  # pose-conditioned when a kind needs the pose
    field.eval()
    return field


def render_all(specs: Sequence[PropertySpec], outputs: Dict, ray_samples: RaySamples, bundle: RayBundle) -> Dict:
    weights = volume_weights(ray_samples, outputs[FieldHeadNames.DENSITY])
    pose = bundle.metadata[POSE_METADATA_KEY].view(-1, 3, 4)[..., :3]
    context = RenderContext(world_to_camera=pose.transpose(-1, -2))
    return {spec.name: spec.kind.render(outputs[spec.name], weights, context) for spec in specs}


def _swapped(specs: Sequence[PropertySpec]) -> Dict[str, str]:
    return {spec.name: ("nv" if spec.branch == "v" else "v") for spec in specs}


@pytest.mark.parametrize("subset", SUBSETS, ids=lambda s: "+".join(s) or "rgb_only")
def test_registry_field_renderer_shapes(subset) -> None:
    bundle = make_bundle()
    ray_samples = make_samples(bundle)
    key_sets: List[set] = []
    for swap in (False, True):
        specs = resolve_properties(subset)
        if swap:
            specs = resolve_properties(subset, branches=_swapped(specs))
            assert all(spec.branch != REGISTRY[spec.name].branch for spec in specs)
        assert [spec.name for spec in specs] == ["rgb", *subset]
        field = make_field(specs)
        # Each decoder branch predicts exactly the properties assigned to it.
        for branch in ("v", "nv"):
            expected = [spec.name for spec in specs if spec.branch == branch]
            if expected:
                assert field.decoders[branch].names == expected
            else:
                assert branch not in field.decoders
        with torch.no_grad():
            outputs = field(ray_samples)
        keys = set(outputs)
        assert keys == {FieldHeadNames.DENSITY, "rgb", *subset}
        key_sets.append(keys)
        assert outputs[FieldHeadNames.DENSITY].shape == (NUM_RAYS, NUM_SAMPLES, 1)
        assert (outputs[FieldHeadNames.DENSITY] >= 0).all()
        for spec in specs:
            values = outputs[spec.name]
            channels = spec.kind.head_channels(NUM_CLASSES)
            assert values.shape == (NUM_RAYS, NUM_SAMPLES, channels), spec.name
            assert torch.isfinite(values).all()
            sigmoid = isinstance(spec.kind, ScalarKind) and spec.kind.activation_name == "sigmoid"
            if isinstance(spec.kind, ColorKind) or sigmoid:
                assert ((values >= 0) & (values <= 1)).all(), spec.name
            if isinstance(spec.kind, ScalarKind) and spec.kind.activation_name == "relu":
                assert (values >= 0).all()
        rendered = render_all(specs, outputs, ray_samples, bundle)
        for spec in specs:
            assert rendered[spec.name].shape == (NUM_RAYS, spec.kind.head_channels(NUM_CLASSES)), spec.name
            assert torch.isfinite(rendered[spec.name]).all()
        if "normals" in subset:
            # world-mode normals come out as a unit vector in the (n+1)/2 encoding
            decoded = rendered["normals"] * 2 - 1
            assert torch.allclose(decoded.norm(dim=-1), torch.ones(NUM_RAYS), atol=1e-4)
    assert key_sets[0] == key_sets[1]


LABELLED = [spec for spec in REGISTRY.values() if spec.file_key is not None]


@pytest.mark.parametrize("spec", LABELLED, ids=[spec.name for spec in LABELLED])
def test_every_kind_reads_back_what_it_encodes(spec: PropertySpec, tmp_path) -> None:
    """A rendered prediction written as a label file (`encode`, what ssnerf-export-dataset writes) reads back (`read`,
    what training reads) as a label that shows as that prediction, in the kind's label channels."""
    height, width = 6, 5
    generator = torch.Generator().manual_seed(0)
    raw = torch.randn(height * width, 1, spec.kind.head_channels(NUM_CLASSES), generator=generator)
    prediction = spec.kind.render(spec.kind.activation(raw), torch.ones(height * width, 1, 1), RenderContext())
    prediction = prediction.reshape(height, width, -1)
    path = tmp_path / "label.png"
    Image.fromarray(spec.kind.encode(prediction)).save(path)
    label = spec.kind.read(path, width, height, NUM_CLASSES)
    assert label.shape == (height, width, spec.kind.label_channels(NUM_CLASSES))
    assert spec.kind.valid(label).all()
    palette = torch.rand(NUM_CLASSES, 3)
    shown_label = spec.display(spec.kind.label_as_prediction(label, NUM_CLASSES), palette)
    assert torch.allclose(shown_label, spec.display(prediction, palette), atol=1.0 / 255 + 1e-6)


def test_branches_condition_on_view_direction_and_pose() -> None:
    """v sees the view direction (not the pose); nv sees the pose (when conditioned) but not the direction."""
    specs = resolve_properties(OPTIONAL_PROPERTIES, normals_mode="pose")
    field = make_field(specs)
    assert field.pose_encoding is not None and make_field(resolve_properties(OPTIONAL_PROPERTIES)).pose_encoding is None
    dirs = torch.nn.functional.normalize(torch.tensor([[1.0, 0.2, 0.1], [0.0, 1.0, 0.3]]), dim=-1)
    base = make_samples(make_bundle(2, directions=dirs))
    other_dir = make_samples(make_bundle(2, directions=dirs[[1, 0]]))
    other_pose = make_samples(make_bundle(2, directions=dirs, rotation=_rotation_z(0.7)))
    # Same positions for the direction swap: feed identical positions by re-using the base frustums.
    other_dir.frustums.origins = base.frustums.origins
    other_dir.frustums.starts = base.frustums.starts
    other_dir.frustums.ends = base.frustums.ends
    with torch.no_grad():
        out_base = field(base)
        out_pose = field(other_pose)
    v_names = [spec.name for spec in specs if spec.branch == "v"]
    nv_names = [spec.name for spec in specs if spec.branch == "nv"]
    assert set(v_names) == {"rgb", "shading", "keypoints", "edges"}
    assert set(nv_names) == {"semantics", "normals"}
    for name in v_names:
        assert torch.allclose(out_base[name], out_pose[name]), name
    for name in nv_names:
        assert not torch.allclose(out_base[name], out_pose[name]), name

    # direction dependence, positions fixed: evaluate the branches directly on the same feature
    feature = torch.randn(2, NUM_SAMPLES, field.encoder.feature_dim)
    with torch.no_grad():
        v_a = field.decoders["v"](field.branch_inputs("v", base, feature))
        v_b = field.decoders["v"](field.branch_inputs("v", other_dir, feature))
        nv_a = field.decoders["nv"](field.branch_inputs("nv", base, feature))
        nv_b = field.decoders["nv"](field.branch_inputs("nv", other_dir, feature))
    assert not torch.allclose(v_a["rgb"], v_b["rgb"])
    for name in nv_names:
        assert torch.allclose(nv_a[name], nv_b[name])


def test_pose_conditioned_field_reads_the_pose_and_defaults_to_identity() -> None:
    """The pose is a decoder input; rays without one (nerfstudio's exporter probes) get the identity pose."""
    specs = resolve_properties(["semantics", "normals"], normals_mode="pose")
    field = make_field(specs)
    identity = make_bundle(pose=False)
    identity.metadata = {POSE_METADATA_KEY: torch.eye(4)[:3].reshape(1, 12).expand(NUM_RAYS, 12).clone()}
    with torch.no_grad():
        without = field(make_samples(make_bundle(pose=False)))["normals"]
        assert torch.allclose(without, field(make_samples(identity))["normals"])
        outputs = field(make_samples(make_bundle(pose=True)))
    assert not torch.allclose(outputs["normals"], without)  # the pose (here translated) changes the prediction
    assert outputs["normals"].shape == (NUM_RAYS, NUM_SAMPLES, 3)
    # pose mode: sigmoid activation, the camera-frame encoding directly
    assert ((outputs["normals"] >= 0) & (outputs["normals"] <= 1)).all()
    # without pose conditioning the metadata is not needed
    plain = make_field(resolve_properties(["semantics", "normals"]))
    with torch.no_grad():
        outputs = plain(make_samples(make_bundle(pose=False)))
        assert set(outputs) == {FieldHeadNames.DENSITY, "rgb", "semantics", "normals"}


def test_positional_encoder_field_runs() -> None:
    specs = resolve_properties(OPTIONAL_PROPERTIES)
    field = make_field(specs, encoder="positional")
    bundle = make_bundle()
    samples = make_samples(bundle)
    with torch.no_grad():
        outputs = field(samples)
    rendered = render_all(specs, outputs, samples, bundle)
    assert rendered["semantics"].shape == (NUM_RAYS, NUM_CLASSES)
    # the paper's encoder size (8x256, input concatenated again after the 4th layer)
    paper = PositionalMLPEncoder()
    with torch.no_grad():
        density, feature = paper(torch.rand(NUM_RAYS, NUM_SAMPLES, 3) * 4 - 2)
    assert density.shape == (NUM_RAYS, NUM_SAMPLES, 1) and feature.shape == (NUM_RAYS, NUM_SAMPLES, 256)


def test_the_registry_names_existing_losses_and_metrics() -> None:
    """Every loss and metric the registry names exists (the docs' registry table is generated from the registry)."""
    assert all(spec.loss in LOSSES and spec.metric in METRICS for spec in REGISTRY.values())
    # the paper's ReLU dies on a mostly-zero target (an empty map for good); sigmoid as for shading and edges
    assert REGISTRY["keypoints"].kind.activation_name == "sigmoid"


def test_resolve_properties_order_and_overrides() -> None:
    specs = resolve_properties(["edges", "semantics"], branches={"semantics": "v"}, weights={"edges": 3.0},
                               normals_mode="pose")
    assert [spec.name for spec in specs] == ["rgb", "semantics", "edges"]
    assert specs[1].branch == "v" and specs[1].weight == 0.04
    assert specs[2].weight == 3.0 and specs[2].branch == "v"
    # the registry itself is untouched by overrides
    assert REGISTRY["semantics"].branch == "nv" and REGISTRY["edges"].weight == 0.4
    normals = resolve_properties(["normals"], normals_mode="pose")[1]
    assert isinstance(normals.kind, NormalKind) and normals.kind.mode == "pose"
    assert REGISTRY["normals"].kind.mode == "world"
    assert resolve_properties(["normals"])[1].kind.mode == "world"
    assert [spec.name for spec in resolve_properties([])] == ["rgb"]


def test_loss_override_replaces_only_the_named_property() -> None:
    specs = {spec.name: spec for spec in resolve_properties(["edges", "keypoints"], losses={"edges": "mse"})}
    assert specs["edges"].loss == "mse" and specs["keypoints"].loss == "l1"
    assert REGISTRY["edges"].loss == "l1"


def test_lite_trains_edges_and_keypoints_with_mse_and_the_paper_config_keeps_l1() -> None:
    from ssnerf_method.method_configs import ssnerf_config, ssnerf_lite_config

    assert ssnerf_lite_config.pipeline.model.losses == {"edges": "mse", "keypoints": "mse"}
    assert ssnerf_config.pipeline.model.losses == {}


@pytest.mark.parametrize(
    "kwargs",
    [
        {"names": ["semantics", "depth"]},
        {"names": ["semantics"], "branches": {"semantic": "v"}},
        {"names": ["semantics"], "weights": {"normal": 1.0}},
        {"names": ["edges"], "losses": {"edge": "mse"}},
    ],
)
def test_unknown_property_names_raise(kwargs) -> None:
    with pytest.raises(ValueError, match="Unknown properties"):
        resolve_properties(**kwargs)


def test_model_trains_only_available_properties_with_overrides() -> None:
    """The model resolves its specs through the registry: dataset-less properties dropped, run overrides applied."""
    from nerfstudio.data.scene_box import SceneBox

    from ssnerf_method.model.ssnerf_model import SSNeRFModelConfig

    config = SSNeRFModelConfig(
        properties=("semantics", "normals", "edges"), branches={"semantics": "v"}, loss_weights={"edges": 5.0},
        normals_mode="pose", encoder="hashgrid", grid_levels=2, grid_max_res=16, grid_log2_hashmap_size=8,
        grid_hidden_dim=16, grid_feature_dim=8, decoder_width=16, num_coarse_samples=4, num_fine_samples=4,
    )
    model = config.setup(
        scene_box=SceneBox(aabb=torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])),
        num_train_data=1,
        metadata={"semantic_classes": ["a", "b", "c"], "available_properties": ("semantics", "edges", "shading")},
    )
    assert [spec.name for spec in model.specs] == ["rgb", "semantics", "edges"]
    assert model.num_classes == 3
    by_name = {spec.name: spec for spec in model.specs}
    assert by_name["semantics"].branch == "v" and by_name["edges"].weight == 5.0
    fine = model.sampling.fine_field
    assert fine.decoders["v"].names == ["rgb", "semantics", "edges"] and "nv" not in fine.decoders
    assert fine.decoders["v"].heads.out_features == 3 + 3 + 1
    model.eval()
    bundle = make_bundle()
    with torch.no_grad():
        outputs = model(bundle)
    assert outputs["semantics_logits"].shape == (NUM_RAYS, 3)
    assert outputs["semantics"].shape == (NUM_RAYS, 3)
    assert outputs["edges_value"].shape == (NUM_RAYS, 1) and outputs["edges"].shape == (NUM_RAYS, 3)
    assert "normals" not in outputs and "shading" not in outputs
    assert outputs["level0_edges_value"].shape == (NUM_RAYS, 1)
