"""Time the Ray launcher against the local one.

    python -m benchmarks.benchmark_launcher [--output reports/launcher_benchmark] [--tasks 20]

On an idle machine, one after the other:

- `ssnerf-benchmark --quick` with the local launcher (torch's default threads: every core) and with `--launcher ray`
  (a local Ray instance with every core of this machine, `--cpus-per-run 1`: one single-threaded worker per core),
  each into a fresh folder: the whole command's wall clock;
- the per-run cost of a Ray task: one first run in a fresh worker that only imports the plugin (what each new
  worker pays once), then `--tasks` jobs that do nothing on warm workers, through the same launcher (pickling the
  job, scheduling it, redirecting its output to its log, its `.running` record); the start of the Ray instance is
  reported on its own.

Each benchmark runs in a subprocess of its own, as a user runs it. Times are seconds of wall clock.
"""

from __future__ import annotations

import importlib
import json
import os
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import tyro
from rich.table import Table

from nerfstudio.utils.rich_utils import CONSOLE

from ssnerf_method.experiments.launcher import Job, LauncherOptions, RayLauncher


@dataclass
class BenchmarkLauncherConfig:
    """Wall clock of `ssnerf-benchmark --quick` with each launcher, and a Ray task's own cost."""

    output: Path = Path("reports/launcher_benchmark")
    """Scratch folder (emptied first) and where `launcher_benchmark.json` is written."""
    tasks: int = 20
    """No-op jobs timed for the per-task cost."""


def quick(folder: Path, *arguments: str) -> float:
    """Seconds of one `ssnerf-benchmark --quick` in its own process, with torch's default threads (every core) in the
    driver; Ray gives each worker the threads of its --cpus-per-run."""
    env = {key: value for key, value in os.environ.items() if key != "OMP_NUM_THREADS"}
    env["RAY_AUTH_MODE"] = "disabled"
    start = time.time()
    subprocess.run([sys.executable, "-m", "ssnerf_method.cli.benchmark", "--quick", "--output", str(folder),
                    *arguments], env=env, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.time() - start


def nothing() -> None:
    """A job's work that takes no time."""


def task_cost(folder: Path, tasks: int) -> tuple:
    """Seconds to start a local Ray instance; of a first run in a fresh worker that only imports the plugin's
    benchmark (worker start and imports: what each new worker pays once); and per no-op run on warm workers (what
    the launcher itself adds to every run), 1 CPU each."""
    import ray

    start = time.time()
    ray.init(log_to_driver=False, include_dashboard=False, configure_logging=False)
    started = time.time() - start
    try:
        first = Job("import", partial(importlib.import_module, "ssnerf_method.experiments.benchmark"),
                    folder / "import.done", folder / "import.log")
        start = time.time()
        RayLauncher(LauncherOptions(launcher="ray")).run([first])  # a fresh worker: starts, imports torch, nerfstudio
        first_run = time.time() - start
        jobs = [Job(f"noop/{index}", nothing, folder / f"noop_{index}.done", folder / f"noop_{index}.log")
                for index in range(tasks)]
        RayLauncher(LauncherOptions(launcher="ray")).run(jobs[:2])  # warm: every worker has started
        start = time.time()
        RayLauncher(LauncherOptions(launcher="ray")).run(jobs[2:])
        per_task = (time.time() - start) / (tasks - 2)
    finally:
        ray.shutdown()
    return started, first_run, per_task


def main(config: BenchmarkLauncherConfig) -> dict:
    shutil.rmtree(config.output, ignore_errors=True)
    config.output.mkdir(parents=True)
    results = {
        "quick_local_seconds": quick(config.output / "local"),
        "quick_ray_seconds": quick(config.output / "ray", "--launcher", "ray", "--cpus-per-run", "1"),
    }
    results["ray_start_seconds"], results["ray_first_run_seconds"], results["ray_seconds_per_task"] = task_cost(
        config.output / "noop", config.tasks)
    results["cpus"] = os.cpu_count()
    table = Table(title="ssnerf-benchmark --quick, local vs Ray launcher (seconds)")
    for column in ("what", "seconds"):
        table.add_column(column)
    table.add_row("--quick, local launcher", f"{results['quick_local_seconds']:.1f}")
    table.add_row(f"--quick, Ray launcher ({results['cpus']} workers of 1 CPU)", f"{results['quick_ray_seconds']:.1f}")
    table.add_row("starting a local Ray instance", f"{results['ray_start_seconds']:.1f}")
    table.add_row("first run in a fresh worker (worker start, imports)", f"{results['ray_first_run_seconds']:.1f}")
    table.add_row("one no-op run through the Ray launcher, warm workers", f"{results['ray_seconds_per_task']:.3f}")
    CONSOLE.print(table)
    (config.output / "launcher_benchmark.json").write_text(json.dumps(results, indent=2))
    return results


def entrypoint() -> None:
    main(tyro.cli(BenchmarkLauncherConfig))


if __name__ == "__main__":
    entrypoint()
