"""The gathered hash-grid lookup: nerfstudio's features bit for bit, its gradients, and where the model uses it."""

from __future__ import annotations

import copy

import pytest
import torch

from nerfstudio.field_components.encodings import HashEncoding

from ssnerf_method.fields.encoders import GatheredHashEncoding, gather_hash_lookups

from test_rendering import tiny_model


def hash_grid() -> HashEncoding:
    torch.manual_seed(0)
    grid = HashEncoding(num_levels=4, min_res=4, max_res=64, log2_hashmap_size=10, implementation="torch")
    with torch.no_grad():  # nerfstudio starts the table near zero; spread it so that a wrong corner shows
        grid.hash_table.uniform_(-1.0, 1.0)
    return grid


def points() -> torch.Tensor:
    generator = torch.Generator().manual_seed(1)
    inside = torch.rand(500, 3, generator=generator)
    on_vertices = torch.tensor([[0.0, 0.0, 0.0], [0.5, 0.25, 0.125], [1.0, 1.0, 1.0], [0.25, 0.5, 0.75]])
    return torch.cat([inside, on_vertices])  # grid vertices: ceiling and floor coincide


def test_gathered_lookup_gives_nerfstudio_features_and_gradients() -> None:
    reference = hash_grid()
    gathered = copy.deepcopy(reference)
    assert gather_hash_lookups(torch.nn.Sequential(gathered)) == 1
    assert isinstance(gathered, GatheredHashEncoding)
    x = points()
    expected, got = reference(x), gathered(x)
    assert torch.equal(expected, got)
    upstream = torch.randn_like(expected)
    (expected * upstream).sum().backward()
    (got * upstream).sum().backward()
    assert reference.hash_table.grad is not None and gathered.hash_table.grad is not None
    assert reference.hash_table.grad.abs().max() > 0
    torch.testing.assert_close(gathered.hash_table.grad, reference.hash_table.grad, rtol=1e-5, atol=1e-5)
    nothing = torch.zeros(0, 3)  # a batch without samples (e.g. every ray culled) keeps its shape
    assert gathered(nothing).shape == reference(nothing).shape == (0, reference.get_out_dim())


@pytest.mark.parametrize("lookup, expected", [("gathered", GatheredHashEncoding), ("nerfstudio", HashEncoding)])
def test_the_model_switches_every_torch_hash_grid(lookup: str, expected: type) -> None:
    model = tiny_model(sampling="proposal", num_proposal_samples=(4,), proposal_max_res=(16,), num_field_samples=4,
                       hash_lookup=lookup)
    grids = [module for module in model.modules() if isinstance(module, HashEncoding)]
    assert len(grids) == 2  # the field's F_enc and the proposal network
    assert all(type(grid) is expected for grid in grids)
    reference = tiny_model(sampling="proposal", num_proposal_samples=(4,), proposal_max_res=(16,),
                           num_field_samples=4, hash_lookup="nerfstudio")
    assert list(model.state_dict()) == list(reference.state_dict())  # checkpoints load either way
