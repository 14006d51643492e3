"""The gathered hash-grid lookup: nerfstudio's features bit for bit, its gradients, and where the model uses it; and
which decoders see the class grid (`class_grid_max_res`)."""

from __future__ import annotations

import copy

import pytest
import torch
from torch.profiler import profile

from nerfstudio.field_components.encodings import HashEncoding

from ssnerf_method.fields import encoders
from ssnerf_method.fields.encoders import GatheredHashEncoding, GatherRows, add_rows, gather_hash_lookups
from ssnerf_method.fields.ssnerf_field import SSNeRFField

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


def test_gathered_rows_backward_is_one_serial_sum_also_when_compiled() -> None:
    """`add_rows` sums repeated indices as `index_add_` does (an empty index gives float zeros), and the compiled
    gather's backward calls it instead of inlining an atomic scatter: same gradient as eager `index_select`."""
    generator = torch.Generator().manual_seed(2)
    index = torch.cat([torch.randint(0, 6, (400,), generator=generator), torch.tensor([9, 9, 9])])  # row 9 thrice
    values = torch.randn(403, 2, generator=generator)
    summed = add_rows(index, values, 12)
    torch.testing.assert_close(summed, torch.zeros(12, 2).index_add_(0, index, values))
    assert bool((summed[6:9] == 0).all()) and bool((summed[9] != 0).all())
    empty = add_rows(torch.zeros(0, dtype=torch.long), torch.zeros(0, 2), 3)
    assert empty.dtype == torch.float32 and torch.equal(empty, torch.zeros(3, 2))

    table = torch.randn(12, 2, generator=generator, requires_grad=True)
    weights = torch.randn(403, 2, generator=generator)
    (torch.index_select(table, 0, index) * weights).sum().backward()
    expected, table.grad = table.grad, None
    compiled = torch.compile(lambda t, i: (GatherRows.apply(t, i) * weights).sum(), dynamic=False)
    compiled(table, index).backward()  # the first call compiles
    table.grad = None
    with profile() as trace:
        compiled(table, index).backward()
    torch.testing.assert_close(table.grad, expected)
    assert any(event.name == "ssnerf::add_rows" for event in trace.events())


def test_add_rows_sums_its_columns_on_two_threads_only_where_torch_has_two(monkeypatch: pytest.MonkeyPatch) -> None:
    """With one torch thread `add_rows` stays on the calling thread; with two it hands the second column to its worker
    thread. Either way every column is one serial sum, so the two give the same bits."""
    generator = torch.Generator().manual_seed(3)
    index = torch.randint(0, 50, (20000,), generator=generator)
    values = torch.randn(20000, 3, generator=generator)
    threads = torch.get_num_threads()
    monkeypatch.setattr(encoders, "_column_worker", None)
    try:
        torch.set_num_threads(1)
        alone = add_rows(index, values, 64)
        assert encoders._column_worker is None
        torch.set_num_threads(2)
        shared = add_rows(index, values, 64)
        assert encoders._column_worker is not None
    finally:
        torch.set_num_threads(threads)
    assert torch.equal(alone, shared)
    torch.testing.assert_close(shared, torch.zeros(64, 3).index_add_(0, index, values))


def test_the_model_switches_every_torch_hash_grid_and_keeps_their_checkpoint_names() -> None:
    model = tiny_model(sampling="proposal", num_proposal_samples=(4,), proposal_max_res=(16,), num_field_samples=4)
    grids = [module for module in model.modules() if isinstance(module, HashEncoding)]
    assert len(grids) == 2  # the field's F_enc and the proposal network
    assert all(type(grid) is GatheredHashEncoding for grid in grids)
    plain = HashEncoding(num_levels=grids[0].num_levels, log2_hashmap_size=grids[0].log2_hashmap_size,
                         features_per_level=grids[0].features_per_level)
    assert list(grids[0].state_dict()) == list(plain.state_dict())  # checkpoints load into either


@pytest.mark.parametrize("sharing, gridded", [("branch", ("semantics",)), ("property", ("semantics",)),
                                             ("property", ("semantics", "normals")),
                                             ("branch", ("normals",))])
def test_the_class_grid_reaches_the_decoders_it_is_given_to_only(sharing: str, gridded: tuple) -> None:
    """The class grid (`class_grid_max_res`) is an input of the MLPs that decode `class_grid_properties` (semantics
    by default) and of no other: those send it gradients, RGB and the other properties neither read it nor change it
    (whatever MLPs they share)."""
    torch.manual_seed(0)
    model = tiny_model(sampling="proposal", num_proposal_samples=(4,), proposal_max_res=(16,), num_field_samples=4,
                       decoder_sharing=sharing, class_grid_max_res=32, class_grid_properties=gridded)
    field = next(module for module in model.modules() if isinstance(module, SSNeRFField))
    grid = field.class_grid
    assert isinstance(grid, GatheredHashEncoding) and grid.num_levels == 4
    with torch.no_grad():
        grid.hash_table.uniform_(-1.0, 1.0)
    positions = torch.rand(64, 3) * 2.0 - 1.0
    directions = torch.nn.functional.normalize(torch.randn(64, 3), dim=-1)
    _, outputs = field.evaluate(positions, directions, None)
    for name, values in outputs.items():
        (gradient,) = torch.autograd.grad(values.sum(), grid.hash_table, retain_graph=True, allow_unused=True)
        reaches = gradient is not None and bool(gradient.abs().max() > 0)
        assert reaches == (name in gridded), name
    with torch.no_grad():  # other class-grid features: the gridded properties change, nothing else does
        grid.hash_table.uniform_(-1.0, 1.0)
    _, again = field.evaluate(positions, directions, None)
    assert all(not torch.allclose(again[name], outputs[name]) for name in gridded)
    assert all(torch.equal(again[name], outputs[name]) for name in outputs if name not in gridded)


def test_without_classes_or_at_zero_there_is_no_class_grid_and_checkpoints_keep_their_names() -> None:
    plain = tiny_model()
    assert not [name for name in plain.state_dict() if "class_grid" in name]
    without_classes = tiny_model(properties=("normals", "shading"), class_grid_max_res=32)
    assert not [name for name in without_classes.state_dict() if "class_grid" in name]
    normals_gridded = tiny_model(properties=("normals", "shading"), class_grid_max_res=32,
                                 class_grid_properties=("semantics", "normals"))
    assert [name for name in normals_gridded.state_dict() if "class_grid" in name]
    with pytest.raises(ValueError, match="class_grid_properties: colour is not a property"):
        tiny_model(class_grid_max_res=32, class_grid_properties=("colour",))
    assert list(tiny_model(class_grid_max_res=0).state_dict()) == list(plain.state_dict())


def _half_plane_accuracy(frequencies: int) -> float:
    """Train only the semantics decoder of a tiny field on two floors (y = -0.4 class 0, y = 0.4 class 1) where
    x < 0, then classify their points where x > 0, which no label reached."""
    torch.manual_seed(0)
    model = tiny_model(properties=("semantics",), sampling="proposal", num_proposal_samples=(4,),
                       proposal_max_res=(16,), num_field_samples=4, decoder_sharing="property",
                       class_grid_max_res=32, class_grid_frequencies=frequencies)
    field = next(module for module in model.modules() if isinstance(module, SSNeRFField))
    generator = torch.Generator().manual_seed(2)

    def floors(x_low: float, x_high: float, count: int) -> tuple:
        xz = torch.rand(count, 2, generator=generator) * torch.tensor([x_high - x_low, 1.6]) + torch.tensor(
            [x_low, -0.8])
        labels = torch.arange(count) % 2
        positions = torch.stack([xz[:, 0], torch.where(labels == 0, -0.4, 0.4), xz[:, 1]], dim=-1)
        return positions, labels

    positions, labels = floors(-0.9, -0.05, 512)
    directions = torch.nn.functional.normalize(torch.randn(512, 3, generator=generator), dim=-1)
    semantics = [p for name, p in field.named_parameters() if "semantics" in name or "class_grid" in name]
    optimizer = torch.optim.Adam(semantics, lr=1e-2)
    for _ in range(150):
        optimizer.zero_grad()
        _, outputs = field.evaluate(positions, directions, None)
        torch.nn.functional.cross_entropy(outputs["semantics"], labels).backward()
        optimizer.step()
    unseen, truth = floors(0.3, 0.9, 512)
    with torch.no_grad():
        _, outputs = field.evaluate(unseen, directions, None)
    return float((outputs["semantics"].argmax(-1) == truth).float().mean())


def test_class_grid_sinusoids_carry_a_class_along_a_surface_no_label_reached() -> None:
    """`class_grid_frequencies`: the semantics decoder also sees smooth sinusoids of the position, so classes
    labelled on one half of two floors carry on to the other half; with the hash grid alone (blank there, e_x alike
    on both floors) the unlabelled half is a guess."""
    assert _half_plane_accuracy(4) > 0.95
    assert _half_plane_accuracy(0) < 0.75


def test_class_grid_sinusoids_reach_the_class_valued_decoder_only_and_keep_checkpoint_names() -> None:
    torch.manual_seed(0)
    options = dict(sampling="proposal", num_proposal_samples=(4,), proposal_max_res=(16,), num_field_samples=4,
                   decoder_sharing="property", class_grid_max_res=32, class_grid_properties=("semantics", "normals"))
    model, plain = tiny_model(**options, class_grid_frequencies=3), tiny_model(**options)
    shapes, plain_shapes = ({name: tuple(value.shape) for name, value in m.state_dict().items()}
                            for m in (model, plain))
    assert list(shapes) == list(plain_shapes)  # no new parameters: a checkpoint's names stay
    widened = {name for name in shapes if shapes[name] != plain_shapes[name]}
    assert widened and all("semantics" in name and "mlp" in name for name in widened), widened
    sinusoids = 3 + 3 * 2 * 3  # the positions, then a sine and a cosine per axis and octave
    assert all(shapes[name][1] - plain_shapes[name][1] == sinusoids for name in widened)
