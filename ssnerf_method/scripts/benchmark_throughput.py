"""Training throughput (rays/s) of SS-NeRF against RGB-only SS-NeRF and nerfstudio's vanilla NeRF, in one run.

    python -m ssnerf_method.scripts.benchmark_throughput [--data DIR] [--steps 30] [--warmup 5] [--rays 1024] \
        [--time-budget 60] [--cases a b] [--rounds 3]

Five cases, all at the same rays per batch:

  (a) `ssnerf-lite`, all five properties          (a)/(b): what the properties cost on the lite architecture
  (b) `ssnerf-lite`, RGB only (`properties=()`)
  (c) nerfstudio's `vanilla-nerf`                   (d)/(c): the paper's architecture with every property against
  (d) `ssnerf` (paper sizes), all properties              plain NeRF at equal rays and samples (coarse + fine)
  (e) (a) with nerfstudio's hash-grid lookup        (a)/(e): what the gathered lookup (`fields/encoders.py`) buys
      (`hash_lookup=nerfstudio`)

Each case builds its pipeline and optimizers straight from the method config (no Trainer, no viewer, no logging),
runs `--warmup` untimed training steps and then times `--steps` steps: loss dict, summed loss, backward, optimizer
and scheduler step, zero_grad, plus the model's before/after-iteration training callbacks, as the Trainer does.
Rays/s = rays per batch x timed steps / seconds. Torch's thread count is left as it is. With `--rounds N` the cases
take turns N times and each reports its median round, so a ratio compares cases timed in the same minutes.

(c) and (d) (8x256 MLPs, 64 + 64 samples per ray) take ~10 s per step on 2 CPU cores, so each case's timing stops
once `--time-budget` seconds are spent (after at least `--min-steps` steps); the table shows the steps timed.
"""

from __future__ import annotations

import contextlib
import copy
import functools
import gc
import json
import os
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, ContextManager, Dict, List, Literal, Optional, Tuple
from unittest import mock

import torch
import tyro

from nerfstudio.configs.method_configs import method_configs as nerfstudio_method_configs
from nerfstudio.data.dataparsers.nerfstudio_dataparser import NerfstudioDataParserConfig
from nerfstudio.engine.callbacks import TrainingCallbackAttributes, TrainingCallbackLocation
from nerfstudio.engine.optimizers import Optimizers
from nerfstudio.engine.trainer import TrainerConfig
from nerfstudio.utils.rich_utils import CONSOLE

from ssnerf_method.method_configs import ssnerf_config, ssnerf_lite_config
from ssnerf_method.properties import OPTIONAL_PROPERTIES
from ssnerf_method.scene.make_scene import MakeSceneConfig, make_scene


@dataclass
class BenchmarkConfig:
    """Measure training throughput of ssnerf-lite (with / without properties), vanilla-nerf and ssnerf."""

    data: Optional[Path] = None
    """Dataset folder in the SS-NeRF format. Default: render the default scene into a temporary folder."""
    steps: int = 30
    """Timed training steps per case."""
    warmup: int = 5
    """Untimed training steps per case before timing (allocations, lazy initialisation)."""
    rays: int = 1024
    """Rays per training batch, for every case."""
    time_budget: float = 60.0
    """Seconds of timed steps per case: timing stops early once they are spent (after at least `min_steps`
    steps), so the paper-sized cases (c) and (d), ~10 s/step on 2 CPU cores, keep the run to a few minutes.
    Warm-up stops early after a quarter of it (after at least 2 steps). 0 disables the budget."""
    min_steps: int = 3
    """Fewest timed steps per case when the time budget cuts timing short."""
    cases: Tuple[Literal["a", "b", "c", "d", "e"], ...] = ("a", "b", "c", "d", "e")
    """Cases to run (a ratio is printed when both of its cases ran)."""
    rounds: int = 1
    """Times every case is timed, the cases taking turns (a b a b ...), so that a drift in the machine's speed (which
    on a shared 2-core machine can reach a fifth within minutes) falls on every case alike; each case reports its
    median round."""
    output: Optional[Path] = None
    """Optional JSON file to save the numbers to."""

    def __post_init__(self) -> None:
        if self.rounds < 1:
            raise ValueError(f"--rounds is how often each case is timed, at least 1; got {self.rounds}")


@dataclass
class CaseResult:
    key: str
    label: str
    method: str
    properties: List[str]
    rays_per_batch: int
    steps: int
    seconds: float

    @property
    def ms_per_step(self) -> float:
        return 1000.0 * self.seconds / self.steps

    @property
    def rays_per_second(self) -> float:
        return self.rays_per_batch * self.steps / self.seconds

    def to_dict(self) -> Dict:
        return {
            "case": self.key, "label": self.label, "method": self.method, "properties": self.properties,
            "rays_per_batch": self.rays_per_batch, "steps": self.steps, "seconds": self.seconds,
            "ms_per_step": self.ms_per_step, "rays_per_second": self.rays_per_second,
        }


# --------------------------------------------------------------------------------------------------------- data


def prepare_data(tmp_root: Path) -> Path:
    """The embedded default scene (`ssnerf-make-scene` defaults) in a temporary folder."""
    out = tmp_root / "scene"
    CONSOLE.print(f"Rendering the default scene into {out} ...")
    make_scene(MakeSceneConfig(out))
    return out


# ------------------------------------------------------------------------------------------------------ configs


def _device_type() -> str:
    return "cuda" if torch.cuda.is_available() else "cpu"


def _ssnerf_case(base: TrainerConfig, data: Path, rays: int, properties, **model) -> TrainerConfig:
    config = copy.deepcopy(base)
    for key, value in model.items():
        setattr(config.pipeline.model, key, value)
    config.machine.device_type = _device_type()
    config.vis = "tensorboard"
    config.pipeline.datamanager.data = data
    config.pipeline.datamanager.train_num_rays_per_batch = rays
    config.pipeline.model.properties = tuple(properties)
    return config


def _vanilla_nerf_case(data: Path, rays: int) -> TrainerConfig:
    """nerfstudio's vanilla-nerf at `ssnerf`'s samples per ray (coarse + importance) and near/far planes."""
    config = copy.deepcopy(nerfstudio_method_configs["vanilla-nerf"])
    config.machine.device_type = _device_type()
    config.vis = "tensorboard"
    datamanager = config.pipeline.datamanager
    # vanilla-nerf defaults to the blender dataparser; read the same transforms.json with nerfstudio's parser (the
    # plugin's parser subclasses it with the same defaults, so the cameras and scaling are identical).
    datamanager.dataparser = NerfstudioDataParserConfig(data=data)
    datamanager.data = data
    datamanager.train_num_rays_per_batch = rays
    model, paper = config.pipeline.model, ssnerf_config.pipeline.model
    model.num_coarse_samples = paper.num_coarse_samples  # 64, as ssnerf's coarse field
    model.num_importance_samples = paper.num_fine_samples  # 64 (default 128); PDFSampler keeps the coarse ones too
    model.collider_params = {"near_plane": paper.near_plane, "far_plane": paper.far_plane}
    return config


class _NoLPIPS(torch.nn.Module):
    """Stand-in for torchmetrics' LPIPS (eval-only metric, never called in training)."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__()

    def forward(self, *args, **kwargs) -> torch.Tensor:
        return torch.zeros(())


def _offline_vanilla_nerf() -> ContextManager:
    # nerfstudio's NeRFModel.populate_modules builds LearnedPerceptualImagePatchSimilarity, whose constructor
    # downloads AlexNet weights and fails offline. The class is imported inside populate_modules with
    # `from torchmetrics.image.lpip import LearnedPerceptualImagePatchSimilarity` (nerfstudio/models/vanilla_nerf.py),
    # i.e. looked up on the module `torchmetrics.image.lpip` at call time, so patching that module attribute while
    # the pipeline is built swaps in the stand-in. LPIPS is an eval metric only: training throughput is unaffected.
    return mock.patch("torchmetrics.image.lpip.LearnedPerceptualImagePatchSimilarity", _NoLPIPS)


# ---------------------------------------------------------------------------------------------------- benchmark


def _sync(device: str) -> None:
    if device.startswith("cuda"):
        torch.cuda.synchronize()


def time_training(
    config: TrainerConfig,
    steps: int,
    warmup: int,
    time_budget: float = 0.0,
    min_steps: int = 3,
    setup_context: Optional[Callable[[], ContextManager]] = None,
) -> Tuple[int, float]:
    """Build pipeline + optimizers from `config`, run the warm-up, return (timed steps, their seconds)."""
    device = config.machine.device_type
    torch.manual_seed(0)
    context = setup_context() if setup_context is not None else contextlib.nullcontext()
    with context:
        pipeline = config.pipeline.setup(device=device, test_mode="val")
    pipeline.train()
    optimizers = Optimizers(config.optimizers, pipeline.get_param_groups())
    callbacks = pipeline.get_training_callbacks(
        TrainingCallbackAttributes(optimizers=optimizers, grad_scaler=None, pipeline=pipeline, trainer=None)
    )

    def train_step(step: int) -> None:
        for callback in callbacks:
            callback.run_callback_at_location(step, location=TrainingCallbackLocation.BEFORE_TRAIN_ITERATION)
        optimizers.zero_grad_all()
        _, loss_dict, _ = pipeline.get_train_loss_dict(step=step)
        loss = functools.reduce(torch.add, loss_dict.values())
        loss.backward()
        optimizers.optimizer_step_all()
        optimizers.scheduler_step_all(step)
        for callback in callbacks:
            callback.run_callback_at_location(step, location=TrainingCallbackLocation.AFTER_TRAIN_ITERATION)

    step = 0
    start = time.perf_counter()
    while step < warmup:
        train_step(step)
        step += 1
        if time_budget > 0 and step >= 2 and time.perf_counter() - start > time_budget / 4:
            break
    _sync(device)
    timed = 0
    start = time.perf_counter()
    while timed < steps:
        train_step(step)
        step += 1
        timed += 1
        if time_budget > 0 and timed >= min_steps:
            _sync(device)
            if time.perf_counter() - start > time_budget:
                break
    _sync(device)
    return timed, time.perf_counter() - start


def _load_average() -> Optional[float]:
    try:
        return round(os.getloadavg()[0], 2)
    except (AttributeError, OSError):
        return None


def format_table(results: Dict[str, CaseResult]) -> str:
    rows = [("case", "method", "properties", "rays/batch", "steps", "ms/step", "rays/s")]
    for result in results.values():
        props = ",".join(result.properties) if result.properties else "rgb only"
        rows.append((result.key, result.method, props, str(result.rays_per_batch), str(result.steps),
                     f"{result.ms_per_step:.1f}", f"{result.rays_per_second:.0f}"))
    widths = [max(len(row[col]) for row in rows) for col in range(len(rows[0]))]
    lines = ["  ".join(cell.ljust(width) for cell, width in zip(row, widths)).rstrip() for row in rows]
    lines.insert(1, "  ".join("-" * width for width in widths))
    return "\n".join(lines)


def run(config: BenchmarkConfig) -> Dict:
    with tempfile.TemporaryDirectory(prefix="ssnerf_bench_") as tmp:
        data = config.data if config.data is not None else prepare_data(Path(tmp))
        data = Path(data)
        device = _device_type()
        paper = ssnerf_config.pipeline.model
        samples = paper.num_coarse_samples + paper.num_fine_samples
        CONSOLE.print(f"data: {data}  device: {device}  torch threads: {torch.get_num_threads()}  "
                      f"steps: {config.steps} (+{config.warmup} warm-up)  rays/batch: {config.rays}")

        cases = [
            ("a", "ssnerf-lite, all properties", "ssnerf-lite", list(OPTIONAL_PROPERTIES),
             lambda: _ssnerf_case(ssnerf_lite_config, data, config.rays, OPTIONAL_PROPERTIES), None),
            ("b", "ssnerf-lite, RGB only", "ssnerf-lite", [],
             lambda: _ssnerf_case(ssnerf_lite_config, data, config.rays, ()), None),
            ("c", f"vanilla-nerf, {paper.num_coarse_samples}+{paper.num_fine_samples} samples", "vanilla-nerf", [],
             lambda: _vanilla_nerf_case(data, config.rays), _offline_vanilla_nerf),
            ("d", f"ssnerf (paper), all properties, {paper.num_coarse_samples}+{paper.num_fine_samples} samples",
             "ssnerf", list(OPTIONAL_PROPERTIES),
             lambda: _ssnerf_case(ssnerf_config, data, config.rays, OPTIONAL_PROPERTIES), None),
            ("e", "ssnerf-lite, all properties, nerfstudio's hash lookup", "ssnerf-lite", list(OPTIONAL_PROPERTIES),
             lambda: _ssnerf_case(ssnerf_lite_config, data, config.rays, OPTIONAL_PROPERTIES,
                                  hash_lookup="nerfstudio"), None),
        ]
        load_before = _load_average()
        rounds: Dict[str, List[CaseResult]] = {}
        for round_index in range(config.rounds):
            for key, label, method, properties, build, context in cases:
                if key not in config.cases:
                    continue
                CONSOLE.print(f"({key}) {label}" + (f", round {round_index + 1}" if config.rounds > 1 else "") + " ...")
                steps, seconds = time_training(
                    build(), config.steps, config.warmup, config.time_budget, config.min_steps, context
                )
                result = CaseResult(key, label, method, properties, config.rays, steps, seconds)
                rounds.setdefault(key, []).append(result)
                gc.collect()  # the case's pipeline went with time_training's frame; free its memory before the next
                if torch.cuda.is_available():
                    torch.cuda.empty_cache()
                CONSOLE.print(f"    {result.ms_per_step:.1f} ms/step, {result.rays_per_second:.0f} rays/s")
        results = {key: sorted(timed, key=lambda result: result.ms_per_step)[(len(timed) - 1) // 2]
                   for key, timed in rounds.items()}

    load_after = _load_average()
    ratios = {
        f"{num}/{den}": results[num].rays_per_second / results[den].rays_per_second
        for num, den in (("a", "b"), ("d", "c"), ("a", "e"))
        if num in results and den in results
    }
    print()
    print(format_table(results))
    print()
    if "a/b" in ratios:
        print(f"(a)/(b) ssnerf-lite all properties / RGB only:              {ratios['a/b']:.3f}x throughput")
    if "d/c" in ratios:
        print(f"(d)/(c) ssnerf all properties / vanilla-nerf ({samples} samples/ray): {ratios['d/c']:.3f}x throughput")
    if "a/e" in ratios:
        print(f"(a)/(e) ssnerf-lite gathered / nerfstudio's hash lookup:    {ratios['a/e']:.3f}x throughput")
    busy = [load for load in (load_before, load_after) if load is not None and load > (os.cpu_count() or 1) + 0.5]
    if device == "cpu" and busy:
        print(f"Note: 1-min load average {load_before} before / {load_after} after on {os.cpu_count()} cores: other "
              "processes shared the CPU, so absolute rays/s are low and the ratios noisy; rerun on an idle machine.")

    report = {
        "device": device,
        "torch_threads": torch.get_num_threads(),
        "data": str(config.data) if config.data is not None else "generated (temporary)",
        "max_steps": config.steps,
        "warmup": config.warmup,
        "time_budget_s": config.time_budget,
        "rays_per_batch": config.rays,
        "load_average_1min": {"before": load_before, "after": load_after},
        "samples_per_ray_c_d": samples,
        "rounds": config.rounds,
        "cases": {key: result.to_dict() for key, result in results.items()},
        "ms_per_step_by_round": {key: [result.ms_per_step for result in timed] for key, timed in rounds.items()},
        "ratios": ratios,
    }
    if config.output is not None:
        config.output.parent.mkdir(parents=True, exist_ok=True)
        config.output.write_text(json.dumps(report, indent=2))
        CONSOLE.print(f"Saved to {config.output}")
    return report


def entrypoint() -> None:
    """CLI entry point."""
    run(tyro.cli(BenchmarkConfig))


if __name__ == "__main__":
    entrypoint()
