"""The compiled training step (the model's `compile`): the same outputs and gradients as eager, an eager fallback,
when the model compiles, unchanged checkpoints.

The two tests that compile share one tiny model (a 2-level hash grid, 16-wide decoders, one proposal network), so
the suite pays for one small compile of the field and one of the proposal network."""

from __future__ import annotations

import copy
from types import SimpleNamespace
from typing import Dict, List

import pytest
import torch

from nerfstudio.cameras.rays import Frustums, RaySamples
from nerfstudio.engine.callbacks import TrainingCallbackAttributes
from nerfstudio.field_components.field_heads import FieldHeadNames

from ssnerf_method.fields import compiled as compiled_module
from ssnerf_method.fields.compiled import CompileConfig, CompiledOrEager, native_bfloat16
from ssnerf_method.model.ssnerf_model import SSNeRFModel

from test_rendering import tiny_model

LITE = dict(sampling="proposal", num_proposal_samples=(6,), proposal_max_res=(16,), num_field_samples=5,
            direction_encoding="sh", density_activation="trunc_exp", decoder_sharing="property", decoder_layers=2,
            class_grid_max_res=32)
"""`ssnerf-lite`'s architecture at a tiny size (`tiny_model` shrinks the grid and the decoders)."""


def lite_model(**overrides) -> SSNeRFModel:
    torch.manual_seed(0)
    model = tiny_model(**{**LITE, **overrides})
    with torch.no_grad():  # spread the hash tables (nerfstudio starts them near zero) so that every corner counts
        for name, parameter in model.named_parameters():
            if name.endswith("hash_table"):
                parameter.uniform_(-1.0, 1.0)
    model.train()
    return model


def run_for(steps: int) -> TrainingCallbackAttributes:
    """What a trainer of a `steps`-step run hands the model."""
    trainer = SimpleNamespace(config=SimpleNamespace(max_num_iterations=steps))
    return TrainingCallbackAttributes(optimizers=None, grad_scaler=None, pipeline=None, trainer=trainer)  # type: ignore


def samples(num_rays: int = 7, num_samples: int = 5) -> RaySamples:
    """Samples spread over the contracted scene, inside and outside the unit box."""
    generator = torch.Generator().manual_seed(3)
    shape = (num_rays, num_samples)
    starts = torch.rand(*shape, 1, generator=generator) * 3.0
    return RaySamples(frustums=Frustums(
        origins=torch.rand(*shape, 3, generator=generator) * 2.0 - 1.0,
        directions=torch.nn.functional.normalize(torch.randn(*shape, 3, generator=generator), dim=-1),
        starts=starts, ends=starts + 0.05, pixel_area=torch.ones(*shape, 1),
    ))


def outputs_and_gradients(model: SSNeRFModel, evaluate) -> tuple[Dict[str, torch.Tensor], Dict[str, torch.Tensor]]:
    """`evaluate(model)`'s tensors, and the gradients a fixed weighting of them sends into the model's parameters."""
    model.zero_grad(set_to_none=True)
    outputs = evaluate(model)
    generator = torch.Generator().manual_seed(5)
    loss = sum((values * torch.randn(values.shape, generator=generator)).sum() for values in outputs.values())
    loss.backward()
    gradients = {name: parameter.grad.clone() for name, parameter in model.named_parameters()
                 if parameter.grad is not None}
    return {name: values.detach() for name, values in outputs.items()}, gradients


@pytest.fixture(scope="module")
def eager_and_compiled() -> List[SSNeRFModel]:
    """The same tiny lite model three times: eager; compiled as a long run compiles it, in float32; compiled with
    bfloat16 matmuls, as on a CPU that has them (one compile per module and precision)."""
    eager = lite_model(compile=CompileConfig(bfloat16_matmuls=False))
    compiled = copy.deepcopy(eager)
    compiled.get_training_callbacks(run_for(1000))
    mixed = copy.deepcopy(eager)
    mixed.config.compile.bfloat16_matmuls = True
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(compiled_module, "native_bfloat16", lambda: True)
        mixed.get_training_callbacks(run_for(1000))
    return [eager, compiled, mixed]


def assert_same(eager: Dict[str, torch.Tensor], compiled: Dict[str, torch.Tensor]) -> None:
    assert eager.keys() == compiled.keys()
    for name in eager:
        torch.testing.assert_close(compiled[name], eager[name], rtol=1e-4, atol=1e-5, msg=name)


def field_outputs(model: SSNeRFModel, ray_samples: RaySamples) -> Dict[str, torch.Tensor]:
    return {str(name): values for name, values in model.sampling.field_module(ray_samples).items()}


def test_the_compiled_field_gives_the_eager_outputs_and_gradients(eager_and_compiled: List[SSNeRFModel]) -> None:
    eager, compiled, _ = eager_and_compiled
    ray_samples = samples()
    expected, expected_gradients = outputs_and_gradients(eager, lambda model: field_outputs(model, ray_samples))
    got, gradients = outputs_and_gradients(compiled, lambda model: field_outputs(model, ray_samples))
    assert compiled.sampling.field_module.compiled_evaluate.compiled is not None, "compiling fell back to eager"
    assert set(expected) == {"rgb", "semantics", "normals", "shading", str(FieldHeadNames.DENSITY)}
    assert_same(expected, got)
    assert set(expected_gradients) >= {"sampling.field_module.encoder.mlp.model.0.hash_table",
                                       "sampling.field_module.decoders.v.decoders.rgb.heads.weight"}
    assert_same(expected_gradients, gradients)


def test_the_compiled_proposal_network_gives_the_eager_densities_and_gradients(
    eager_and_compiled: List[SSNeRFModel],
) -> None:
    eager, compiled, _ = eager_and_compiled
    positions = samples(num_rays=9, num_samples=6).frustums.get_positions()
    assert isinstance(compiled.sampling.density_fns[0], type(lambda: None))  # the flattening wrapper

    def density(model: SSNeRFModel) -> Dict[str, torch.Tensor]:
        return {"density": model.sampling.density_fns[0](positions)}

    expected, expected_gradients = outputs_and_gradients(eager, density)
    got, gradients = outputs_and_gradients(compiled, density)
    assert_same(expected, got)
    assert any(name.startswith("sampling.proposal_networks.0") for name in expected_gradients)
    assert_same(expected_gradients, gradients)


def relative_errors(got: Dict[str, torch.Tensor], expected: Dict[str, torch.Tensor]) -> Dict[str, float]:
    assert got.keys() == expected.keys()
    return {name: float((got[name] - expected[name]).norm() / expected[name].norm()) for name in expected
            if expected[name].norm() > 0}


def test_bfloat16_matmuls_stay_near_float32_and_hand_back_float32(eager_and_compiled: List[SSNeRFModel]) -> None:
    """bfloat16 keeps 8 bits of mantissa: outputs and gradients move by about a percent, not more, and nothing in
    bfloat16 leaks into rendering, losses or the optimizer."""
    eager, _, mixed = eager_and_compiled
    ray_samples = samples()
    positions = ray_samples.frustums.get_positions()

    def outputs(model: SSNeRFModel) -> Dict[str, torch.Tensor]:
        return {**field_outputs(model, ray_samples), "proposal": model.sampling.density_fns[0](positions)}

    expected, expected_gradients = outputs_and_gradients(eager, outputs)
    got, gradients = outputs_and_gradients(mixed, outputs)
    assert mixed.sampling.field_module.compiled_evaluate.compiled is not None, "compiling fell back to eager"
    assert all(values.dtype == torch.float32 for values in [*got.values(), *gradients.values()])
    output_errors, gradient_errors = relative_errors(got, expected), relative_errors(gradients, expected_gradients)
    assert 0 < max(output_errors.values()) < 0.03, output_errors  # (0: autocast did nothing)
    assert max(gradient_errors.values()) < 0.1, gradient_errors
    assert {"sampling.field_module.encoder.mlp.model.0.hash_table", "sampling.proposal_networks.0.encoding.hash_table"
            } <= {name for name, error in gradient_errors.items() if error > 0}


@pytest.mark.parametrize("amx, avx512_bf16, native", [(True, False, True), (False, True, True), (False, False, False),
                                                      (None, None, False)])
def test_native_bfloat16_reads_the_cpu_probes(monkeypatch, amx, avx512_bf16, native: bool) -> None:
    """Either instruction set counts; a torch without the (private) probes counts as neither."""
    for name, value in (("_is_amx_tile_supported", amx), ("_is_avx512_bf16_supported", avx512_bf16)):
        if value is None:
            monkeypatch.delattr(torch.cpu, name)
        else:
            monkeypatch.setattr(torch.cpu, name, lambda value=value: value)
    assert native_bfloat16() is native


@pytest.mark.parametrize("native, asked, in_bfloat16", [(True, True, True), (False, True, False),
                                                         (True, False, False)])
def test_bfloat16_matmuls_only_where_the_cpu_has_them(monkeypatch, native: bool, asked: bool,
                                                      in_bfloat16: bool) -> None:
    compiled_with = []
    monkeypatch.setattr(compiled_module, "native_bfloat16", lambda: native)
    monkeypatch.setattr(CompiledOrEager, "__init__", lambda self, function, label, bfloat16_matmuls=False:
                        compiled_with.append(bfloat16_matmuls))
    lite_model(compile=CompileConfig(bfloat16_matmuls=asked)).get_training_callbacks(run_for(1000))
    assert compiled_with == [in_bfloat16] * 2  # the field and the proposal network


def test_evaluation_never_calls_the_compiled_field() -> None:
    model = lite_model()
    model.get_training_callbacks(run_for(1000))
    field = model.sampling.field_module
    field.compiled_evaluate = "not a function"  # type: ignore[assignment]  (fails if called)
    model.eval()
    density = field(samples())[FieldHeadNames.DENSITY]
    assert density.shape == (7, 5, 1)
    model.train()
    with pytest.raises(TypeError):
        field(samples())


@pytest.mark.parametrize("attributes, enabled, compiles", [
    (run_for(1000), True, True),
    (run_for(299), True, False),  # shorter than compile.min_steps (300)
    (run_for(1000), False, False),
    (TrainingCallbackAttributes(optimizers=None, grad_scaler=None, pipeline=None, trainer=None), True, False),
    (None, True, False),
])
def test_only_long_cpu_runs_compile(attributes, enabled: bool, compiles: bool) -> None:
    model = lite_model(compile=CompileConfig(enabled=enabled))
    plain = lite_model(compile=CompileConfig(enabled=False))
    model.get_training_callbacks(attributes)
    field = model.sampling.field_module
    assert (getattr(field, "compiled_evaluate", None) is not None) == compiles
    density_fns = model.sampling.density_fns
    assert all(getattr(function, "__self__", None) is not None for function in density_fns) != compiles
    assert list(model.state_dict()) == list(plain.state_dict())  # checkpoints are the same either way
    assert all(model.state_dict()[key].shape == value.shape for key, value in plain.state_dict().items())


def test_a_failed_compile_runs_eagerly_with_one_line(monkeypatch, capsys) -> None:
    calls = []

    def broken(function, **kwargs):
        def run(*args):
            calls.append(args)
            raise RuntimeError("C++ compile error\nfull log ...")
        return run

    monkeypatch.setattr(torch, "compile", broken)
    double = CompiledOrEager(lambda x: 2 * x, "a test function")
    assert torch.equal(double(torch.ones(2)), torch.full((2,), 2.0))
    assert torch.equal(double(torch.ones(3)), torch.full((3,), 2.0))
    assert len(calls) == 1, "a failed compile is not retried"
    lines = [line for line in capsys.readouterr().out.splitlines() if line.strip()]
    assert len(lines) == 1 and "a test function" in lines[0] and "C++ compile error" in lines[0]
    assert "eager" in lines[0]
