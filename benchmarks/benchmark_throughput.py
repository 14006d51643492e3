"""Training throughput (rays/s) of SS-NeRF against RGB-only SS-NeRF and nerfstudio's vanilla NeRF, in one run.

    python -m benchmarks.benchmark_throughput [--data DIR] [--steps 30] [--warmup 12] [--rays 1024] \
        [--time-budget 60] [--cases a b] [--rounds 3] [--threads 2] [--run-steps 1000] [--reference REV]

Six cases, all at the same rays per batch:

  (a) `ssnerf-lite`, all five properties, eager     (a)/(b): what the properties cost on the lite architecture
      (today's step: `compile=CompileConfig(enabled=False)`)
  (b) `ssnerf-lite`, RGB only (`properties=()`)
  (c) nerfstudio's `vanilla-nerf`                   (d)/(c): the paper's architecture with every property against
  (d) `ssnerf` (paper sizes), all properties              plain NeRF at equal rays and samples (coarse + fine)
  (f) (a) with the field and proposal networks      (f)/(a): what compiling buys, steady and over a whole run with
      compiled (`compile.enabled=True`,                    the compile counted (a fresh inductor cache and dynamo
      `compile.bfloat16_matmuls=False`), cold compile      state every round: what a first run on a machine pays)
  (g) (f) with bfloat16 matmuls (the default where     (g)/(f): what bfloat16 buys; (g)/(a): today's default
      the CPU has them in hardware)                         training step against the eager float32 one

Each case builds its pipeline and optimizers straight from the method config (no Trainer, no viewer, no logging),
runs `--warmup` training steps (timed apart: they hold the compile) and then times `--steps` steps: loss dict, summed
loss, backward, optimizer and scheduler step, zero_grad, plus the model's before/after-iteration training callbacks,
as the Trainer does. Rays/s = rays per batch x timed steps / seconds. A `--run-steps` run's time is the warm-up's
seconds plus the remaining steps at the timed rate: compile time included, and for the compiled cases also what the
first compile in a fresh process costs once (inductor's import and workers, measured before the cases: without it
only the first compiled case of round 1 would pay it, and the median round hides it). With `--threads N` torch runs N
threads (else it is left as it is). With `--rounds N` the cases take turns N times and each reports its median round,
so a ratio compares cases timed in the same minutes.

With `--reference REV` (a git revision, such as the commit an issue's "today" was measured at) each round also times
(r): that revision's own case (a), run by its own `benchmark_throughput` in a subprocess from a temporary git worktree
of it, over the same data and threads. Its run estimate is its timed rate alone (its warm-up uncounted), so a ratio
against it errs low.

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
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Callable, ContextManager, Dict, Iterator, List, Literal, Optional, Tuple, cast
from unittest import mock

import torch
import tyro
from torch._inductor.utils import fresh_cache
from torch.autograd.profiler import record_function

from nerfstudio.configs.method_configs import method_configs as nerfstudio_method_configs
from nerfstudio.data.dataparsers.nerfstudio_dataparser import NerfstudioDataParserConfig
from nerfstudio.engine.callbacks import TrainingCallbackAttributes, TrainingCallbackLocation
from nerfstudio.engine.optimizers import Optimizers
from nerfstudio.engine.trainer import Trainer, TrainerConfig
from nerfstudio.utils.rich_utils import CONSOLE

from ssnerf_method.fields.compiled import CompileConfig, native_bfloat16
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
    warmup: int = 12
    """Training steps per case before timing (allocations, lazy initialisation, compilation), timed apart. 12 holds
    every compile of (f): step 10 is the first whose proposal networks run without gradients."""
    rays: int = 1024
    """Rays per training batch, for every case."""
    time_budget: float = 60.0
    """Seconds of timed steps per case: timing stops early once they are spent (after at least `min_steps`
    steps), so the paper-sized cases (c) and (d), ~10 s/step on 2 CPU cores, keep the run to a few minutes.
    Warm-up stops early after a quarter of it (after at least 2 steps) in the cases that compile nothing. 0 disables
    the budget."""
    min_steps: int = 3
    """Fewest timed steps per case when the time budget cuts timing short."""
    cases: Tuple[Literal["a", "b", "c", "d", "f", "g"], ...] = ("a", "b", "c", "d", "f", "g")
    """Cases to run (a ratio is printed when both of its cases ran)."""
    rounds: int = 1
    """Times every case is timed, the cases taking turns (a b a b ...), so that a drift in the machine's speed (which
    on a shared 2-core machine can reach a fifth within minutes) falls on every case alike; each case reports its
    median round."""
    threads: Optional[int] = None
    """Torch threads (`torch.set_num_threads`); None leaves torch's default."""
    run_steps: int = 1000
    """Length of the training run whose time (warm-up, compile included, then the timed rate) each case reports."""
    output: Optional[Path] = None
    """Optional JSON file to save the numbers to."""
    reference: Optional[str] = None
    """A git revision of this repository whose case (a) is timed too, each round, as case (r) (see above)."""

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
    warmup_steps: int = 0
    warmup_seconds: float = 0.0
    """Seconds of the warm-up steps (compilation included)."""
    startup_seconds: float = 0.0
    """What a compiling run pays once per process besides its own compile (`inductor_startup_seconds`)."""

    @property
    def ms_per_step(self) -> float:
        return 1000.0 * self.seconds / self.steps

    @property
    def rays_per_second(self) -> float:
        return self.rays_per_batch * self.steps / self.seconds

    def run_seconds(self, run_steps: int) -> float:
        """Seconds of a `run_steps`-step run: inductor's start in a fresh process (compiling cases), the warm-up as
        measured, then the timed rate."""
        return (self.startup_seconds + self.warmup_seconds
                + max(run_steps - self.warmup_steps, 0) * self.seconds / self.steps)

    def to_dict(self, run_steps: int = 1000) -> Dict:
        return {
            "case": self.key, "label": self.label, "method": self.method, "properties": self.properties,
            "rays_per_batch": self.rays_per_batch, "steps": self.steps, "seconds": self.seconds,
            "ms_per_step": self.ms_per_step, "rays_per_second": self.rays_per_second,
            "warmup_steps": self.warmup_steps, "warmup_seconds": self.warmup_seconds,
            "startup_seconds": self.startup_seconds,
            "run_steps": run_steps, "run_seconds": self.run_seconds(run_steps),
        }


@dataclass
class Case:
    """One benchmark case: how to build its trainer config, and the context its whole timing runs in."""

    key: str
    label: str
    method: str
    properties: List[str]
    build: Callable[[], TrainerConfig]
    context: Callable[[], ContextManager] = contextlib.nullcontext
    compiles: bool = False
    """Its warm-up holds a compile: never cut short by the time budget."""


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


STAGE_PREFIX = "ssnerf::"
"""Prefix of the profiler ranges a `TrainingStep` opens (`scripts/profile_step.py` reads them)."""


class TrainingStep:
    """One training step as nerfstudio's Trainer runs it, on a pipeline and optimizers built straight from a method
    config (no Trainer, no viewer, no logging): the model's before-iteration callbacks, loss dict, summed loss,
    backward, optimizer and scheduler step, after-iteration callbacks."""

    def __init__(self, config: TrainerConfig) -> None:
        self.device = config.machine.device_type
        torch.manual_seed(0)
        self.pipeline = config.pipeline.setup(device=self.device, test_mode="val")
        self.pipeline.train()
        self.optimizers = Optimizers(config.optimizers, self.pipeline.get_param_groups())
        # the model reads the run's length from the trainer (`compile.min_steps`): a stand-in holding the config
        trainer = cast(Trainer, SimpleNamespace(config=config))
        self.callbacks = self.pipeline.get_training_callbacks(
            TrainingCallbackAttributes(optimizers=self.optimizers, grad_scaler=None, pipeline=self.pipeline,
                                       trainer=trainer)
        )

    def __call__(self, step: int) -> None:
        with record_function(STAGE_PREFIX + "step"):
            with record_function(STAGE_PREFIX + "callbacks"):
                for callback in self.callbacks:
                    callback.run_callback_at_location(step, location=TrainingCallbackLocation.BEFORE_TRAIN_ITERATION)
            with record_function(STAGE_PREFIX + "optimizer"):
                self.optimizers.zero_grad_all()
            _, loss_dict, _ = self.pipeline.get_train_loss_dict(step=step)
            loss = functools.reduce(torch.add, loss_dict.values())
            with record_function(STAGE_PREFIX + "backward"):
                loss.backward()
            with record_function(STAGE_PREFIX + "optimizer"):
                self.optimizers.optimizer_step_all()
                self.optimizers.scheduler_step_all(step)
            with record_function(STAGE_PREFIX + "callbacks"):
                for callback in self.callbacks:
                    callback.run_callback_at_location(step, location=TrainingCallbackLocation.AFTER_TRAIN_ITERATION)


def time_training(
    config: TrainerConfig, steps: int, warmup: int, time_budget: float = 0.0, min_steps: int = 3,
    cut_warmup: bool = True,
) -> Tuple[int, float, int, float]:
    """Build pipeline + optimizers from `config`, run the warm-up, time the steps; returns (timed steps, their
    seconds, warm-up steps, their seconds, the pipeline's construction excluded)."""
    train_step = TrainingStep(config)
    device = train_step.device
    step = 0
    start = time.perf_counter()
    while step < warmup:
        train_step(step)
        step += 1
        if cut_warmup and time_budget > 0 and step >= 2 and time.perf_counter() - start > time_budget / 4:
            break
    _sync(device)
    warmup_steps, warmup_seconds = step, time.perf_counter() - start
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
    return timed, time.perf_counter() - start, warmup_steps, warmup_seconds


@contextlib.contextmanager
def cold_compile() -> Iterator[None]:
    """A first compile on this machine: a fresh inductor cache folder and no in-memory dynamo or inductor state."""
    torch._dynamo.reset()
    with fresh_cache():
        yield
    torch._dynamo.reset()


def inductor_startup_seconds() -> float:
    """What the first compile in a process costs besides compiling: importing inductor and starting its compile
    workers. Every `ns-train` that compiles pays it once; in this benchmark only the first compiling case of the first
    round would, so it is measured here, before any case (a tiny function compiled cold twice: the first time less the
    second), and added to every compiling case's run."""
    def tiny(x: torch.Tensor) -> torch.Tensor:
        return (x.sin() * 2.0).sum()

    seconds = []
    for _ in range(2):
        with cold_compile():
            start = time.perf_counter()
            x = torch.randn(64, requires_grad=True)
            torch.compile(tiny, dynamic=False)(x).backward()
            seconds.append(time.perf_counter() - start)
    return max(seconds[0] - seconds[1], 0.0)


def reference_command(config: BenchmarkConfig, data: Path, output: Path, worktree: Path) -> List[str]:
    """The command that times case (a) with another revision's `benchmark_throughput`, run in that revision's
    worktree (in `benchmarks/`, or in the package's `scripts/` before 2026-12-07). Only options every revision's
    benchmark knows; threads through OMP_NUM_THREADS (`reference_env`)."""
    moved = (worktree / "benchmarks" / "benchmark_throughput.py").is_file()
    module = "benchmarks.benchmark_throughput" if moved else "ssnerf_method.scripts.benchmark_throughput"
    return [sys.executable, "-m", module, "--data", str(data.resolve()),
            "--cases", "a", "--steps", str(config.steps), "--warmup", str(config.warmup), "--rays", str(config.rays),
            "--time-budget", str(config.time_budget), "--output", str(output)]


def reference_env(worktree: Path, threads: Optional[int]) -> Dict[str, str]:
    """The environment of a `reference_command`: the worktree's `ssnerf_method` ahead of the installed one."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(worktree)] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    if threads is not None:
        env["OMP_NUM_THREADS"] = str(threads)
    return env


def reference_result(report: Dict, revision: str) -> CaseResult:
    """Case (r) from the JSON report of another revision's case (a)."""
    timed = report["cases"]["a"]
    return CaseResult("r", f"ssnerf-lite, all properties, as of {revision}", timed["method"], timed["properties"],
                      timed["rays_per_batch"], timed["steps"], timed["seconds"])


@contextlib.contextmanager
def reference_worktree(revision: str) -> Iterator[Path]:
    """A temporary detached git worktree of `revision` of the repository this file is in, removed afterwards."""
    here = Path(__file__).resolve().parent
    try:
        top = subprocess.run(["git", "-C", str(here), "rev-parse", "--show-toplevel"], check=True, text=True,
                             capture_output=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError) as err:
        raise SystemExit(f"--reference {revision}: {here} is not in a git checkout ({err}); run the benchmark from a "
                         "clone of the repository") from None
    with tempfile.TemporaryDirectory(prefix="ssnerf_reference_") as tmp:
        worktree = Path(tmp) / "tree"
        made = subprocess.run(["git", "-C", top, "worktree", "add", "--detach", str(worktree), revision],
                              text=True, capture_output=True)
        if made.returncode != 0:
            reason = " ".join(made.stderr.split())
            raise SystemExit(f"--reference {revision}: git worktree add failed ({reason}); name a commit of this "
                             "repository")
        try:
            yield worktree
        finally:
            subprocess.run(["git", "-C", top, "worktree", "remove", "--force", str(worktree)], capture_output=True)


def time_reference(config: BenchmarkConfig, worktree: Path, data: Path, revision: str) -> CaseResult:
    """One round of case (r): the revision's own benchmark in a subprocess."""
    output = worktree / "reference_a.json"
    done = subprocess.run(reference_command(config, data, output, worktree), cwd=worktree,
                          env=reference_env(worktree, config.threads), text=True, capture_output=True)
    if done.returncode != 0 or not output.is_file():
        tail = (done.stderr.strip().splitlines() or [""])[-1]
        raise SystemExit(f"--reference {revision}: its benchmark failed ({tail[:200]})")
    return reference_result(json.loads(output.read_text()), revision)


def _load_average() -> Optional[float]:
    try:
        return round(os.getloadavg()[0], 2)
    except (AttributeError, OSError):
        return None


def format_table(results: Dict[str, CaseResult], run_steps: int = 1000) -> str:
    rows = [("case", "method", "properties", "rays/batch", "steps", "ms/step", "rays/s", "warm-up s",
             f"{run_steps}-step run s")]
    for result in results.values():
        props = ",".join(result.properties) if result.properties else "rgb only"
        rows.append((result.key, result.method, props, str(result.rays_per_batch), str(result.steps),
                     f"{result.ms_per_step:.1f}", f"{result.rays_per_second:.0f}",
                     f"{result.warmup_seconds:.1f} ({result.warmup_steps})", f"{result.run_seconds(run_steps):.0f}"))
    widths = [max(len(row[col]) for row in rows) for col in range(len(rows[0]))]
    lines = ["  ".join(cell.ljust(width) for cell, width in zip(row, widths)).rstrip() for row in rows]
    lines.insert(1, "  ".join("-" * width for width in widths))
    return "\n".join(lines)


def run(config: BenchmarkConfig) -> Dict:
    if config.threads is not None:
        torch.set_num_threads(config.threads)
    with tempfile.TemporaryDirectory(prefix="ssnerf_bench_") as tmp:
        data = config.data if config.data is not None else prepare_data(Path(tmp))
        data = Path(data)
        device = _device_type()
        paper = ssnerf_config.pipeline.model
        samples = paper.num_coarse_samples + paper.num_fine_samples
        CONSOLE.print(f"data: {data}  device: {device}  torch threads: {torch.get_num_threads()}  "
                      f"steps: {config.steps} (+{config.warmup} warm-up)  rays/batch: {config.rays}")

        cases = [
            Case("a", "ssnerf-lite, all properties, eager", "ssnerf-lite", list(OPTIONAL_PROPERTIES),
                 lambda: _ssnerf_case(ssnerf_lite_config, data, config.rays, OPTIONAL_PROPERTIES,
                                      compile=CompileConfig(enabled=False))),
            Case("b", "ssnerf-lite, RGB only", "ssnerf-lite", [],
                 lambda: _ssnerf_case(ssnerf_lite_config, data, config.rays, (), compile=CompileConfig(enabled=False))),
            Case("c", f"vanilla-nerf, {paper.num_coarse_samples}+{paper.num_fine_samples} samples", "vanilla-nerf", [],
                 lambda: _vanilla_nerf_case(data, config.rays), _offline_vanilla_nerf),
            Case("d", f"ssnerf (paper), all properties, {paper.num_coarse_samples}+{paper.num_fine_samples} "
                 "samples", "ssnerf", list(OPTIONAL_PROPERTIES),
                 lambda: _ssnerf_case(ssnerf_config, data, config.rays, OPTIONAL_PROPERTIES,
                                      compile=CompileConfig(enabled=False))),
            Case("f", "ssnerf-lite, all properties, compiled (cold), float32", "ssnerf-lite",
                 list(OPTIONAL_PROPERTIES),
                 lambda: _ssnerf_case(ssnerf_lite_config, data, config.rays, OPTIONAL_PROPERTIES,
                                      compile=CompileConfig(bfloat16_matmuls=False)), cold_compile, compiles=True),
            Case("g", "ssnerf-lite, all properties, compiled (cold), bfloat16 matmuls"
                 + ("" if native_bfloat16() else " (not native here: float32)"), "ssnerf-lite",
                 list(OPTIONAL_PROPERTIES),
                 lambda: _ssnerf_case(ssnerf_lite_config, data, config.rays, OPTIONAL_PROPERTIES,
                                      compile=CompileConfig(bfloat16_matmuls=True)), cold_compile, compiles=True),
        ]
        load_before = _load_average()
        startup = 0.0
        if any(case.compiles and case.key in config.cases for case in cases):
            startup = inductor_startup_seconds()
            CONSOLE.print(f"inductor's start in this process (import, compile workers): {startup:.1f} s, added to "
                          "every compiled case's run")
        rounds: Dict[str, List[CaseResult]] = {}
        reference = (reference_worktree(config.reference) if config.reference is not None
                     else contextlib.nullcontext(None))
        with reference as worktree:
            for round_index in range(config.rounds):
                which_round = f", round {round_index + 1}" if config.rounds > 1 else ""
                if worktree is not None:
                    CONSOLE.print(f"(r) case (a) as of {config.reference}, in a subprocess{which_round} ...")
                    result = time_reference(config, worktree, data, cast(str, config.reference))
                    rounds.setdefault("r", []).append(result)
                    CONSOLE.print(f"    {result.ms_per_step:.1f} ms/step, {result.rays_per_second:.0f} rays/s")
                for case in cases:
                    if case.key not in config.cases:
                        continue
                    CONSOLE.print(f"({case.key}) {case.label}{which_round} ...")
                    with case.context():
                        steps, seconds, warmup_steps, warmup_seconds = time_training(
                            case.build(), config.steps, config.warmup, config.time_budget, config.min_steps,
                            cut_warmup=not case.compiles,
                        )
                    result = CaseResult(case.key, case.label, case.method, case.properties, config.rays, steps, seconds,
                                        warmup_steps, warmup_seconds, startup if case.compiles else 0.0)
                    rounds.setdefault(case.key, []).append(result)
                    gc.collect()  # the case's pipeline went with time_training's frame; free its memory before the next
                    if torch.cuda.is_available():
                        torch.cuda.empty_cache()
                    CONSOLE.print(f"    {result.ms_per_step:.1f} ms/step, {result.rays_per_second:.0f} rays/s; warm-up "
                                  f"{warmup_steps} steps in {warmup_seconds:.1f} s")
        results = {key: sorted(timed, key=lambda result: result.ms_per_step)[(len(timed) - 1) // 2]
                   for key, timed in rounds.items()}

    load_after = _load_average()
    # the speed-ups also reported over a whole run (compile and start-up counted)
    run_pairs = [(num, den) for num, den in (("f", "a"), ("g", "a"), ("a", "r"), ("f", "r"), ("g", "r"))
                 if num in results and den in results]
    ratios = {
        f"{num}/{den}": results[num].rays_per_second / results[den].rays_per_second
        for num, den in [("a", "b"), ("d", "c"), ("g", "f"), *run_pairs]
        if num in results and den in results
    }
    run_ratios = {
        f"{num}/{den}": results[den].run_seconds(config.run_steps) / results[num].run_seconds(config.run_steps)
        for num, den in run_pairs
    }
    print()
    print(format_table(results, config.run_steps))
    print()
    if "a/b" in ratios:
        print(f"(a)/(b) ssnerf-lite all properties / RGB only:              {ratios['a/b']:.3f}x throughput")
    if "d/c" in ratios:
        print(f"(d)/(c) ssnerf all properties / vanilla-nerf ({samples} samples/ray): {ratios['d/c']:.3f}x throughput")
    if "a/e" in ratios:
        print(f"(a)/(e) ssnerf-lite gathered / nerfstudio's hash lookup:    {ratios['a/e']:.3f}x throughput")
    if "f/a" in ratios:
        print(f"(f)/(a) ssnerf-lite compiled / eager:                       {ratios['f/a']:.3f}x throughput, "
              f"{run_ratios['f/a']:.3f}x steps per second over a {config.run_steps}-step run, compile included")
    if "g/f" in ratios:
        print(f"(g)/(f) ssnerf-lite compiled, bfloat16 / float32 matmuls:   {ratios['g/f']:.3f}x throughput")
    if "g/a" in ratios:
        print(f"(g)/(a) ssnerf-lite compiled with bfloat16 / eager:         {ratios['g/a']:.3f}x throughput, "
              f"{run_ratios['g/a']:.3f}x steps per second over a {config.run_steps}-step run, compile included")
    for num in ("a", "f", "g"):
        if f"{num}/r" in ratios:
            print(f"({num})/(r) this {results[num].label} / (a) as of {config.reference}: {ratios[f'{num}/r']:.3f}x "
                  f"throughput, {run_ratios[f'{num}/r']:.3f}x steps per second over a {config.run_steps}-step run")
    busy = [load for load in (load_before, load_after) if load is not None and load > (os.cpu_count() or 1) + 0.5]
    print(f"torch threads: {torch.get_num_threads()}; 1-min load average {load_before} before / {load_after} after on "
          f"{os.cpu_count()} cores")
    if device == "cpu" and busy:
        print("Note: other processes shared the CPU, so absolute rays/s are low and the ratios noisy (with several "
              "threads most of all); rerun on an idle machine.")

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
        "run_steps": config.run_steps,
        "reference": config.reference,
        "cases": {key: result.to_dict(config.run_steps) for key, result in results.items()},
        "ms_per_step_by_round": {key: [result.ms_per_step for result in timed] for key, timed in rounds.items()},
        "ratios": ratios,
        "run_ratios": run_ratios,
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
