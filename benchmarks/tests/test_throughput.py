"""The measuring tools' own logic: the step profiler's categories and report (`benchmarks/profile_step.py`), and
`benchmarks/benchmark_throughput.py`'s compiled case, run estimate and `--reference` revision."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import pytest

from benchmarks import profile_step
from benchmarks.benchmark_throughput import (
    BenchmarkConfig,
    CaseResult,
    TrainingStep,
    _ssnerf_case,
    reference_command,
    reference_env,
    reference_result,
    reference_worktree,
)
from ssnerf_method.fields.compiled import CompileConfig
from ssnerf_method.method_configs import ssnerf_lite_config
from ssnerf_method.properties import OPTIONAL_PROPERTIES


@pytest.mark.parametrize("name, stage, expected", [
    ("aten::index_select", "field", "hash-grid gather / scatter"),
    ("aten::scatter_add_", "backward", "hash-grid gather / scatter"),
    ("aten::addmm", "decoders", "matmul (MLPs)"),
    ("aten::sqrt", "optimizer", "optimizer (Adam)"),
    ("aten::sqrt", "field", profile_step.ELEMENTWISE),
    ("aten::bitwise_xor", "hash_grid", "hash arithmetic (xor, floor, ceil, mod)"),
    ("## Call CompiledFxGraph abc ##", "field", "compiled"),
    ("aten::searchsorted", "sampling", "sampling (sort, search, gather)"),
])
def test_profile_categories(name: str, stage: str, expected: str) -> None:
    assert profile_step.category(name, stage) == expected


def test_profile_step_reports_stages_kinds_and_arithmetic(tiny_dataset: Path, tmp_path: Path) -> None:
    report = profile_step.run(profile_step.ProfileStepConfig(
        data=tiny_dataset, steps=2, warmup=1, threads=1, rays=64, compile=False, peak_size=256, top=5,
        output_dir=tmp_path / "profile",
    ))
    stages = report["profile"]["stages_ms"]
    for stage in ("data", "proposal_networks", "sampling", "hash_grid", "encoder", "decoders", "losses", "backward",
                  "optimizer"):
        assert stages[stage] > 0, stage
    assert sum(stages.values()) <= report["profile"]["wall_ms"] * 1.01
    kinds = report["profile"]["categories_ms"]
    assert kinds["matmul (MLPs)"]["forward"] > 0 and kinds["matmul (MLPs)"]["backward"] > 0
    assert kinds["hash-grid gather / scatter"]["backward"] > 0  # the table's gradient
    arithmetic = report["arithmetic"]
    assert arithmetic["gflop"] > 0 and arithmetic["peak_gflops"] > 0
    assert 0 < arithmetic["achieved_fraction"] < 1
    text = (tmp_path / "profile" / "step_profile.md").read_text()
    assert "field decoders (forward)" in text and "GFLOP" in text and "eager" in text
    assert json.loads((tmp_path / "profile" / "step_profile.json").read_text())["compiled"] is False


def test_the_benchmark_step_compiles_as_a_long_run_does(tiny_dataset: Path) -> None:
    """`TrainingStep` hands the model its config's run length, so the benchmark times what a real run trains."""
    case = _ssnerf_case(ssnerf_lite_config, tiny_dataset, 32, OPTIONAL_PROPERTIES)
    assert case.max_num_iterations >= case.pipeline.model.compile.min_steps  # type: ignore[attr-defined]
    field = TrainingStep(case).pipeline.model.sampling.field_module
    assert getattr(field, "compiled_evaluate", None) is not None
    eager = TrainingStep(_ssnerf_case(ssnerf_lite_config, tiny_dataset, 32, OPTIONAL_PROPERTIES,
                                         compile=CompileConfig(enabled=False)))
    assert getattr(eager.pipeline.model.sampling.field_module, "compiled_evaluate", None) is None


def test_a_compiled_runs_time_counts_inductors_start_once() -> None:
    """`benchmark_throughput`'s run estimate: inductor's start in a fresh process, the warm-up, then the timed rate."""
    eager = CaseResult("a", "eager", "ssnerf-lite", [], 1024, steps=10, seconds=4.0, warmup_steps=12,
                       warmup_seconds=6.0)
    compiled = CaseResult("g", "compiled", "ssnerf-lite", [], 1024, steps=10, seconds=2.0, warmup_steps=12,
                          warmup_seconds=30.0, startup_seconds=12.0)
    assert eager.run_seconds(1000) == pytest.approx(6.0 + 988 * 0.4)
    assert compiled.run_seconds(1000) == pytest.approx(12.0 + 30.0 + 988 * 0.2)
    assert compiled.to_dict(1000)["startup_seconds"] == 12.0


def test_the_reference_case_runs_another_revisions_own_benchmark(tmp_path: Path) -> None:
    """`--reference REV`: a detached worktree of REV (removed afterwards), its own benchmark's case (a) with only the
    options every revision knows, its package ahead of the installed one, and its timed rate as case (r), whose run
    estimate leaves its warm-up out. An unknown revision ends in one line naming it."""
    config = BenchmarkConfig(steps=7, warmup=3, rays=256, threads=2)
    command = reference_command(config, Path("scene"), tmp_path / "r.json", tmp_path)
    assert command[1:3] == ["-m", "ssnerf_method.scripts.benchmark_throughput"]  # a revision before the move
    (tmp_path / "benchmarks").mkdir()
    (tmp_path / "benchmarks" / "benchmark_throughput.py").touch()
    assert reference_command(config, Path("scene"), tmp_path / "r.json", tmp_path)[1:3] == [
        "-m", "benchmarks.benchmark_throughput"]
    assert {"--cases", "--steps", "--warmup", "--rays", "--output"} <= set(command)
    assert command[command.index("--cases") + 1] == "a" and "--threads" not in command
    env = reference_env(tmp_path, 2)
    assert env["PYTHONPATH"].split(os.pathsep)[0] == str(tmp_path) and env["OMP_NUM_THREADS"] == "2"
    timed = {"method": "ssnerf-lite", "properties": ["edges"], "rays_per_batch": 256, "steps": 7, "seconds": 3.5}
    result = reference_result({"cases": {"a": timed}}, "abc123")
    assert (result.key, result.ms_per_step, result.run_seconds(1000)) == ("r", pytest.approx(500.0),
                                                                         pytest.approx(500.0))
    if subprocess.run(["git", "-C", str(Path(__file__).parent), "rev-parse", "HEAD"], capture_output=True).returncode:
        pytest.skip("not a git checkout")
    with reference_worktree("HEAD") as worktree:
        assert (worktree / "benchmarks" / "benchmark_throughput.py").is_file()
    assert not worktree.exists()
    with pytest.raises(SystemExit, match="no-such-revision.*name a commit"):
        with reference_worktree("no-such-revision"):
            pass
