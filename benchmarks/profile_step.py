"""Where an all-properties `ssnerf-lite` training step goes, and how much arithmetic it does against the machine's peak.

    python -m benchmarks.profile_step [--steps 5] [--warmup 12] [--threads 2] [--compile True|False]

Builds the pipeline and optimizers as `benchmark_throughput` does (the default scene, 1024 rays, every property),
runs `--warmup` untimed steps, then profiles `--steps` steps with `torch.profiler` at `--threads` threads and reports:

- the step by stage (data, proposal sampling and its networks, the field's hash grid, encoder MLP and decoders,
  rendering, losses, backward, optimizer), from ranges the step's modules open while it is profiled;
- the self CPU time by kind of operation (hash-grid gathers and their scatter backward, matmuls, elementwise,
  reductions and scans, copies and concatenation, ...), split into forward, backward and optimizer, and the top ops;
- the arithmetic of one step (`torch.utils.flop_counter.FlopCounterMode`: matmuls, forward and backward), the
  machine's measured matmul peak at the same threads (in bfloat16 when the compiled networks multiply in it), and the
  ratio of the two rates.

With the field compiled (`--compile True`, the method's default in CPU runs of 300+ steps) the field is one compiled
region, reported as one stage; the warm-up (12 steps) holds every compile (step 10 is the first whose proposal networks
run without gradients). It writes `step_profile.md` and `step_profile.json` under `--output-dir` (git-ignored
`reports/` by default). Times on a machine that other processes share are inflated, most of all with several threads:
the load average is reported.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import tempfile
import time
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Dict, Iterator, List, Optional, Sequence, Tuple

import torch
import tyro
from torch import nn
from torch.autograd.profiler import record_function
from torch.profiler import ProfilerActivity, profile
from torch.utils.flop_counter import FlopCounterMode

from nerfstudio.field_components.encodings import HashEncoding
from nerfstudio.utils.rich_utils import CONSOLE

from benchmarks.benchmark_throughput import STAGE_PREFIX, TrainingStep, _ssnerf_case, prepare_data
from ssnerf_method.fields.compiled import CompileConfig
from ssnerf_method.method_configs import ssnerf_lite_config
from ssnerf_method.properties import OPTIONAL_PROPERTIES


@dataclass
class ProfileStepConfig:
    """Profile an all-properties ssnerf-lite training step: stages, kinds of operation, arithmetic against peak."""

    data: Optional[Path] = None
    """Dataset folder in the SS-NeRF format. Default: render the default scene into a temporary folder."""
    steps: int = 5
    """Profiled training steps (after the warm-up)."""
    warmup: int = 12
    """Untimed steps first (allocations, lazy initialisation, every compile: step 10 is the first whose proposal
    networks run without gradients)."""
    threads: int = 2
    """Torch threads for the step and for the matmul peak."""
    rays: int = 1024
    """Rays per training batch."""
    compile: Optional[bool] = None
    """Compile the field and proposal networks (the model's `compile.enabled`); None: the method's default."""
    top: int = 25
    """Ops listed in the table of top ops by self CPU time."""
    peak_size: int = 2048
    """Side of the square fp32 matmul that measures the machine's peak."""
    output_dir: Path = Path("reports/profile_step")
    """Folder for step_profile.md and step_profile.json."""


# ------------------------------------------------------------------------------------------------------ stages

STAGES: Tuple[Tuple[str, str], ...] = (
    ("data", "data (ray batch)"),
    ("proposal_networks", "proposal networks (forward)"),
    ("sampling", "proposal sampling (besides the networks)"),
    ("hash_grid", "field hash grid (forward)"),
    ("encoder", "field encoder MLP (forward)"),
    ("decoders", "field decoders (forward)"),
    ("field", "field, rest (contraction, encodings, activations; all of the field when compiled)"),
    ("forward", "rendering and the model's rest (forward)"),
    ("losses", "losses and metrics"),
    ("backward", "backward (all of the above)"),
    ("optimizer", "optimizer (zero_grad, Adam, scheduler)"),
    ("callbacks", "training callbacks"),
    ("step", "the step's rest (Python, loss sum)"),
)
"""Stage keys (the ranges `stage_ranges` and `TrainingStep` open, `STAGE_PREFIX` + key) and their labels, in the order
of a step. Ranges nest (a step holds the forward, which holds sampling, which holds the proposal networks); each stage
is reported exclusive of the stages nested in it."""


def _range_hooks(module: nn.Module, name: str) -> List[torch.utils.hooks.RemovableHandle]:
    """Open a profiler range named `name` around every forward of `module`."""
    opened: List[record_function] = []

    def enter(*_args) -> None:
        opened.append(record_function(name))
        opened[-1].__enter__()

    def leave(*_args) -> None:
        opened.pop().__exit__(None, None, None)

    return [module.register_forward_pre_hook(enter), module.register_forward_hook(leave)]


@contextlib.contextmanager
def stage_ranges(train_step: TrainingStep) -> Iterator[None]:
    """Open the forward stages' ranges around the model's modules while the context lasts (hooks, removed after)."""
    model = train_step.pipeline.model
    sampling = model.sampling
    field = getattr(sampling, "field_module", None)
    compiled = model.config.compile.enabled
    modules: List[Tuple[nn.Module, str]] = [(model, "forward")]
    wrapped = [(train_step.pipeline.datamanager, "next_train", "data"), (model, "get_metrics_dict", "losses"),
               (model, "get_loss_dict", "losses")]
    if hasattr(sampling, "sampler"):
        modules.append((sampling.sampler, "sampling"))
    if field is not None:
        modules.append((field, "field"))
        if not compiled:  # (a hook inside a compiled function would recompile it)
            modules += [(field.encoder, "encoder"), *((decoder, "decoders") for decoder in field.decoders.values())]
            modules += [(grid, "hash_grid") for grid in field.encoder.modules() if isinstance(grid, HashEncoding)]
    handles = [handle for module, key in modules for handle in _range_hooks(module, STAGE_PREFIX + key)]
    for owner, method, key in wrapped:  # an instance attribute in front of the class's method
        setattr(owner, method, _ranged(STAGE_PREFIX + key, getattr(owner, method)))
    density_fns = getattr(sampling, "density_fns", None)
    if density_fns is not None:  # what the proposal sampler calls per network (compiled or not)
        sampling.density_fns = [_ranged(STAGE_PREFIX + "proposal_networks", function) for function in density_fns]
    try:
        yield
    finally:
        for handle in handles:
            handle.remove()
        for owner, method, _ in wrapped:
            delattr(owner, method)  # back to the class's method
        if density_fns is not None:
            sampling.density_fns = density_fns


def _ranged(name: str, function: Callable) -> Callable:
    def wrapped(*args, **kwargs):
        with record_function(name):
            return function(*args, **kwargs)

    return wrapped


# ------------------------------------------------------------------------------------------------ op categories

CATEGORIES: Tuple[Tuple[str, str], ...] = (
    ("compiled", r"CompiledFxGraph|Torch-Compiled Region|CompiledFunction|cpp_fused|TorchDynamo"),
    ("hash-grid gather / scatter", r"::(index_select|index_add_?|scatter_add_?|embedding\w*|index_put_?|"
                                   r"_index_put_impl_|index)$"),
    ("matmul (MLPs)", r"::(mm|addmm|bmm|matmul|linear|_addmm_activation)$"),
    ("hash arithmetic (xor, floor, ceil, mod)", r"::(bitwise_\w+|floor|ceil|remainder|fmod)$"),
    ("reductions and scans", r"::(sum|mean|cumsum|cumprod|prod|max|min|amax|amin|norm|linalg_vector_norm|all|any|"
                             r"argmax|_softmax\w*|_log_softmax\w*|logsumexp|nll_loss\w*|var|std)$"),
    ("sampling (sort, search, gather)", r"::(searchsorted|sort|gather|scatter|flip|topk|rand\w*|uniform_|"
                                        r"normal_|bernoulli_)$"),
    ("copies, cat, fill", r"::(copy_|cat|stack|fill_|zero_|zeros\w*|ones\w*|empty\w*|full\w*|clone|contiguous|to|"
                          r"_to_copy|expand|repeat|split\w*|unbind|narrow|slice|select|view|reshape|"
                          r"as_strided|t|transpose|permute|unsqueeze|squeeze|flatten|detach\w*|new_\w+|"
                          r"resize_|set_|lift_fresh|alias|_unsafe_view)$"),
    ("optimizer (Adam)", r"::(_fused_adam\w*|_foreach_\w+|lerp_|addcmul_|addcdiv_|sqrt|mul_|add_|div_)$"),
)
"""Kinds of operation by op name (first match wins); everything else is "elementwise and other". The optimizer's
in-place ops only count as such inside the optimizer stage (`category`)."""
ELEMENTWISE = "elementwise and other"


def category(name: str, stage: str) -> str:
    """The kind of operation an op of this name is (the optimizer's in-place ops only within its stage)."""
    for label, pattern in CATEGORIES:
        if re.search(pattern, name):
            if label == "optimizer (Adam)" and stage != "optimizer":
                continue
            return label
    return ELEMENTWISE


PHASES = {"backward": "backward", "optimizer": "optimizer"}
"""Stages shown as their own phase in the category table; every other stage counts as forward."""


def _stage_of(event) -> str:
    """The innermost stage range an event runs in ("step" outside every range)."""
    parent = event.cpu_parent
    while parent is not None:
        if parent.name.startswith(STAGE_PREFIX):
            return parent.name[len(STAGE_PREFIX):]
        parent = parent.cpu_parent
    return "step"


@dataclass
class StepProfile:
    """The profiled steps, per step: stage times (exclusive, ms), self CPU time by phase and category, top ops."""

    steps: int
    wall_ms: float
    stages_ms: Dict[str, float]
    categories_ms: Dict[str, Dict[str, float]]
    top_ops: List[Dict]

    @classmethod
    def from_profile(cls, prof: profile, steps: int, wall_seconds: float, top: int) -> "StepProfile":
        events = [event for event in prof.events() if event.device_type == torch.autograd.DeviceType.CPU]
        ranges = [event for event in events if event.name.startswith(STAGE_PREFIX)]
        stages: Dict[str, float] = defaultdict(float)
        for event in ranges:  # exclusive of the nested stage ranges
            nested = _nested_ranges(event)
            stages[event.name[len(STAGE_PREFIX):]] += (event.cpu_time_total - sum(n.cpu_time_total for n in nested))
        categories: Dict[str, Dict[str, float]] = defaultdict(lambda: defaultdict(float))
        ops: Dict[str, Dict] = {}
        for event in events:
            if event.name.startswith(STAGE_PREFIX) or event.self_cpu_time_total <= 0:
                continue
            stage = _stage_of(event)
            kind = category(event.name, stage)
            phase = PHASES.get(stage, "forward")
            categories[kind][phase] += event.self_cpu_time_total
            entry = ops.setdefault(f"{event.name}@{stage}", {"op": event.name, "stage": stage, "category": kind,
                                                             "self_us": 0.0, "calls": 0})
            entry["self_us"] += event.self_cpu_time_total
            entry["calls"] += 1
        per_step = 1e-3 / steps  # us -> ms per step
        ranked = sorted(ops.values(), key=lambda op: -op["self_us"])[:top]
        return cls(
            steps=steps,
            wall_ms=1e3 * wall_seconds / steps,
            stages_ms={key: stages.get(key, 0.0) * per_step for key, _ in STAGES},
            categories_ms={kind: {phase: value * per_step for phase, value in by_phase.items()}
                           for kind, by_phase in categories.items()},
            top_ops=[{"op": op["op"], "stage": op["stage"], "category": op["category"],
                      "self_ms_per_step": op["self_us"] * per_step,
                      "calls_per_step": op["calls"] / steps} for op in ranked],
        )


def _nested_ranges(event) -> List:
    """The stage ranges directly nested in `event` (through any non-range events between)."""
    found = []
    stack = list(event.cpu_children)
    while stack:
        child = stack.pop()
        if child.name.startswith(STAGE_PREFIX):
            found.append(child)
        else:
            stack.extend(child.cpu_children)
    return found


# ------------------------------------------------------------------------------------------------ arithmetic


def step_flops(train_step: TrainingStep, step: int) -> Tuple[int, Dict[str, int]]:
    """Floating-point operations of one training step (matmuls, forward and backward, as `FlopCounterMode` counts
    them), and of the next step's forward by module (the model's modules down to the field's parts)."""
    counter = FlopCounterMode(display=False)
    with counter:
        train_step(step)
    total = int(counter.get_total_flops())
    forward = FlopCounterMode(display=False)
    with forward, torch.no_grad():
        train_step.pipeline.get_train_loss_dict(step=step + 1)
    by_module = {name: int(sum(counts.values())) for name, counts in forward.get_flop_counts().items()
                 if name != "Global" and name.count(".") <= 4 and counts}
    return total, by_module


def matmul_peak(size: int, repeats: int = 10, dtype: torch.dtype = torch.float32) -> float:
    """The best GFLOP/s of a `size`-square matmul in `dtype` at the current thread count."""
    a, b = torch.randn(size, size, dtype=dtype), torch.randn(size, size, dtype=dtype)
    torch.mm(a, b)  # warm-up
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        torch.mm(a, b)
        best = min(best, time.perf_counter() - start)
    return 2.0 * size**3 / best / 1e9


# -------------------------------------------------------------------------------------------------- report


def _load() -> Optional[float]:
    try:
        return round(os.getloadavg()[0], 2)
    except (AttributeError, OSError):
        return None


def _table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines)


def _short(name: str) -> str:
    """An op name fit for a table cell (compiled graphs' names carry a 50-character hash)."""
    name = name.replace("|", "/")
    return name if len(name) <= 60 else name[:57] + "..."


def markdown(report: Dict) -> str:
    """The report as Markdown: stages, kinds of operation, top ops, arithmetic."""
    profile_ms = report["profile"]
    wall = profile_ms["wall_ms"]
    stage_rows = [(label, f"{profile_ms['stages_ms'][key]:.1f}", f"{100 * profile_ms['stages_ms'][key] / wall:.1f}%")
                  for key, label in STAGES]
    phases = ("forward", "backward", "optimizer")
    categories = profile_ms["categories_ms"]
    ordered = sorted(categories, key=lambda kind: -sum(categories[kind].values()))
    total_self = sum(sum(by_phase.values()) for by_phase in categories.values())
    category_rows = [
        (kind, *(f"{categories[kind].get(phase, 0.0):.1f}" for phase in phases),
         f"{sum(categories[kind].values()):.1f}", f"{100 * sum(categories[kind].values()) / total_self:.1f}%")
        for kind in ordered
    ]
    op_rows = [(_short(op["op"]), op["stage"], op["category"], f"{op['self_ms_per_step']:.1f}",
                f"{op['calls_per_step']:.0f}") for op in profile_ms["top_ops"]]
    arithmetic = report["arithmetic"]
    lines = [
        f"# Where an all-properties ssnerf-lite step goes ({report['compiled_label']})",
        "",
        f"{report['rays']} rays per step, properties: {', '.join(report['properties'])}; torch {report['torch']}, "
        f"{report['threads']} threads on {report['cpu_count']} cores; {profile_ms['steps']} profiled steps after "
        f"{report['warmup']} warm-up steps. 1-min load average {report['load_before']} before, {report['load_after']} "
        "after" + (" (other processes shared the CPU: times are inflated)." if report["loaded"] else "."),
        "",
        f"Step wall time under the profiler: **{wall:.0f} ms** (without it, just before: median "
        f"{report['unprofiled_ms']:.0f} ms, the time the arithmetic below is divided by).",
        "",
        "## By stage (exclusive of nested stages, ms per step)",
        "",
        _table(("stage", "ms", "share of the step"), stage_rows),
        "",
        "## By kind of operation (self CPU time, ms per step)",
        "",
        _table(("kind", *phases, "total", "share"), category_rows),
        "",
        f"## Top {len(op_rows)} ops by self CPU time",
        "",
        _table(("op", "stage", "kind", "ms per step", "calls per step"), op_rows),
        "",
        "## Arithmetic against the machine's peak",
        "",
        f"- FLOPs per step (matmuls, forward and backward, `FlopCounterMode`): **{arithmetic['gflop']:.2f} GFLOP**",
        f"- {report['peak_dtype']} matmul peak, {report['peak_size']}-square at {report['threads']} threads: "
        f"**{arithmetic['peak_gflops']:.0f} GFLOP/s**",
        f"- achieved over the whole step: {arithmetic['achieved_gflops']:.1f} GFLOP/s = "
        f"**{100 * arithmetic['achieved_fraction']:.1f}% of peak**",
        f"- within the matmul ops alone: {arithmetic['matmul_gflops']:.1f} GFLOP/s "
        f"({100 * arithmetic['matmul_fraction']:.1f}% of peak)",
        "",
        "The forward's share by module (training forward, no backward):",
        "",
        _table(("module", "forward GFLOP per step"),
               [(name, f"{flops / 1e9:.3f}") for name, flops in sorted(arithmetic["by_module"].items())]),
        "",
    ]
    return "\n".join(lines)


def run(config: ProfileStepConfig) -> Dict:
    torch.set_num_threads(config.threads)
    with tempfile.TemporaryDirectory(prefix="ssnerf_profile_") as tmp:
        data = Path(config.data) if config.data is not None else prepare_data(Path(tmp))
        model = {} if config.compile is None else {"compile": CompileConfig(enabled=config.compile)}
        trainer = _ssnerf_case(ssnerf_lite_config, data, config.rays, OPTIONAL_PROPERTIES, **model)
        compiled = trainer.pipeline.model.compile.enabled
        train_step = TrainingStep(trainer)
        load_before = _load()
        CONSOLE.print(f"{config.warmup} warm-up steps at {config.threads} threads ...")
        step = 0
        for step in range(config.warmup):
            train_step(step)
        timed = max(1, config.steps)
        seconds = []
        for step in range(config.warmup, config.warmup + timed):
            start = time.perf_counter()
            train_step(step)
            seconds.append(time.perf_counter() - start)
        unprofiled_ms = 1e3 * sorted(seconds)[(timed - 1) // 2]  # the median step: a shared machine's spikes aside
        # what the warm-up's compile chose (the model asks for bfloat16 only where the CPU has it)
        field = getattr(train_step.pipeline.model.sampling, "field_module", None)
        bfloat16 = bool(getattr(getattr(field, "compiled_evaluate", None), "bfloat16_matmuls", False))
        CONSOLE.print(f"profiling {config.steps} steps ...")
        first = config.warmup + timed
        with stage_ranges(train_step), profile(activities=[ProfilerActivity.CPU]) as prof:
            start = time.perf_counter()
            for step in range(first, first + config.steps):
                train_step(step)
            wall = time.perf_counter() - start
        step_profile = StepProfile.from_profile(prof, config.steps, wall, config.top)
        flops, by_module = step_flops(train_step, first + config.steps)
        load_after = _load()
    peak_dtype = torch.bfloat16 if bfloat16 else torch.float32
    peak = matmul_peak(config.peak_size, dtype=peak_dtype)
    matmul_ms = sum(step_profile.categories_ms.get("matmul (MLPs)", {}).values())
    seconds = unprofiled_ms / 1e3
    arithmetic = {
        "gflop": flops / 1e9,
        "by_module": by_module,
        "peak_gflops": peak,
        "achieved_gflops": flops / 1e9 / seconds,
        "achieved_fraction": flops / 1e9 / seconds / peak,
        "matmul_gflops": flops / 1e9 / (matmul_ms / 1e3) if matmul_ms > 0 else float("nan"),
        "matmul_fraction": flops / 1e9 / (matmul_ms / 1e3) / peak if matmul_ms > 0 else float("nan"),
    }
    busy = [load for load in (load_before, load_after) if load is not None and load > (os.cpu_count() or 1) + 0.5]
    report = {
        "rays": config.rays,
        "properties": list(OPTIONAL_PROPERTIES),
        "compiled": bool(compiled),
        "compiled_label": ("eager" if not compiled else "field and proposal networks compiled"
                           + (", bfloat16 matmuls" if bfloat16 else "")),
        "peak_dtype": str(peak_dtype).removeprefix("torch."),
        "torch": torch.__version__,
        "threads": config.threads,
        "cpu_count": os.cpu_count(),
        "warmup": config.warmup,
        "peak_size": config.peak_size,
        "load_before": load_before,
        "load_after": load_after,
        "loaded": bool(busy),
        "unprofiled_ms": unprofiled_ms,
        "profile": {
            "steps": step_profile.steps, "wall_ms": step_profile.wall_ms, "stages_ms": step_profile.stages_ms,
            "categories_ms": step_profile.categories_ms, "top_ops": step_profile.top_ops,
        },
        "arithmetic": arithmetic,
    }
    text = markdown(report)
    config.output_dir.mkdir(parents=True, exist_ok=True)
    (config.output_dir / "step_profile.md").write_text(text)
    (config.output_dir / "step_profile.json").write_text(json.dumps(report, indent=2))
    print(text)
    CONSOLE.print(f"Saved {config.output_dir / 'step_profile.md'} and step_profile.json")
    return report


def entrypoint() -> None:
    """CLI entry point."""
    run(tyro.cli(ProfileStepConfig))


if __name__ == "__main__":
    entrypoint()
