"""`--launcher ray`: the quick benchmark on a local 2-CPU Ray instance gives the local launcher's report rows and run
folders; a worker killed mid-run is retried, one killed past its retries is reported as failed with its log while
the other runs are kept; a re-run trains only what is missing, and nothing once all is done."""

from __future__ import annotations

import fcntl
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import List, Set
from unittest import mock

import pytest
import torch

from ssnerf_method.experiments import benchmark
from ssnerf_method.experiments.benchmark import BenchmarkConfig, generated_scenes, run
from ssnerf_method.experiments.launcher import Job, exclusive, launch, ordered

ray = pytest.importorskip("ray", reason="the cluster extra (pip install -e .[cluster]) is not installed")

QUICK = ["--quick", "--launcher", "ray", "--cpus-per-run", "1"]


def driver(output: Path, *arguments: str) -> subprocess.Popen:
    """`ssnerf-benchmark` with the Ray launcher as a user starts it from a terminal: its own process, its own local
    Ray instance (every core of this machine: 2 workers of 1 CPU here)."""
    env = {**os.environ, "OMP_NUM_THREADS": "1", "RAY_AUTH_MODE": "disabled"}
    command = [sys.executable, "-m", "ssnerf_method.cli.benchmark", *QUICK, "--output", str(output),
               *arguments]
    # Ctrl-C reaches it as in a terminal even when pytest itself was started in the background (where SIGINT is
    # ignored and a child Python would inherit that)
    return subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


def finished(process: subprocess.Popen, timeout: float = 1500) -> str:
    output, _ = process.communicate(timeout=timeout)
    assert process.returncode == 0, output[-3000:]
    return output


def results_layout(output: Path) -> Set[str]:
    """Every result file under `output` (metrics, baseline scores, reports, figures), without the launcher's logs,
    locks and records, which only a Ray run writes."""
    kept = {".json", ".md", ".png", ".pt", ".ckpt", ".yml"}
    return {str(path.relative_to(output)) for path in output.rglob("*")
            if path.is_file() and path.suffix in kept and not path.name.endswith(".failed.json")
            and "scenes" not in path.relative_to(output).parts and "events.out" not in path.name}


def checkpoints(paths: Set[str]) -> List[str]:
    return sorted(path for path in paths if path.endswith(".ckpt"))


def test_jobs_are_deduplicated_and_ordered_after_what_they_need(tmp_path: Path) -> None:
    def job(key: str, *after: str) -> Job:
        return Job(key, print, tmp_path / key, tmp_path / f"{key}.log", after)

    jobs = ordered([job("b", "a"), job("a"), job("c", "b", "elsewhere"), job("a", "c")])
    assert [item.key for item in jobs] == ["a", "b", "c"]  # the second "a" is the first one
    with pytest.raises(ValueError, match="cycle"):
        ordered([job("x", "y"), job("y", "x")])
    with exclusive(tmp_path / "run.lock"):  # released on exit: a second holder gets it at once
        pass
    with exclusive(tmp_path / "run.lock"):
        pass
    ran = []
    with mock.patch.object(fcntl, "flock", side_effect=OSError(37, "No locks available")):
        with exclusive(tmp_path / "nfs.lock"):  # a filesystem without locks: the run goes ahead, unguarded
            ran.append(True)
    assert ran == [True]
    assert launch(BenchmarkConfig(launcher="local"), jobs) == {}  # local: the report step trains, not the launcher


@pytest.mark.filterwarnings("ignore")
def test_ray_quick_benchmark_matches_the_local_one_and_a_rerun_trains_nothing(tmp_path: Path, monkeypatch) -> None:
    torch.set_num_threads(1)
    local, distributed = tmp_path / "local", tmp_path / "ray"
    scenes = tuple(generated_scenes(BenchmarkConfig(quick=True, output=tmp_path))[:1])  # one scene: half the runs
    process = driver(distributed, "--scenes", str(scenes[0]))
    local_results = run(BenchmarkConfig(quick=True, output=local, scenes=scenes))
    text = finished(process)
    assert "launcher ray: 10 of 10 runs to do" in text and "10 done, 0 running, 0 failed" in text

    assert results_layout(distributed) == results_layout(local)
    assert len(checkpoints(results_layout(local))) == 7  # 7 models
    ours, theirs = (json.loads((folder / "tables.json").read_text()) for folder in (distributed, local))
    for table in ("table1", "table2_left"):
        assert [sorted(row) for row in ours[table]] == [sorted(row) for row in theirs[table]]
        assert [row["row"] for row in ours[table]] == [row["row"] for row in theirs[table]]
        assert all(value is not None for row in ours[table] for value in row.values())
    assert {scene: set(rows) for scene, rows in ours["results"].items()} == {
        scene: set(rows) for scene, rows in local_results.items()}
    report = (distributed / "report.md").read_text()
    assert "Failed runs" not in report and report.count("| SS-NeRF (walkthrough_seed_") == 1
    logs = list((distributed / "runs").rglob("launcher.log"))
    assert len(logs) == 7 and all("attempt 1 on" in log.read_text() for log in logs)

    def refuse(*args, **kwargs):
        raise AssertionError("a finished run was redone")

    monkeypatch.setattr(benchmark, "train_in_process", refuse)
    monkeypatch.setattr(ray, "init", refuse)  # nothing left to do: no Ray instance is even started
    rerun = run(BenchmarkConfig(quick=True, output=distributed, launcher="ray", scenes=scenes))
    assert {scene: set(rows) for scene, rows in rerun.items()} == {scene: set(rows) for scene, rows in
                                                                    ours["results"].items()}


def kill_attempt(record: Path, attempt: int, process: subprocess.Popen, timeout: float = 600) -> None:
    """Wait until the worker running a job writes `record` for `attempt`, then kill that worker (SIGKILL)."""
    deadline = time.time() + timeout
    while time.time() < deadline:
        assert process.poll() is None, "the benchmark ended before its worker could be killed"
        try:
            running = json.loads(record.read_text())
        except (OSError, ValueError):
            running = None
        if running and running["attempt"] == attempt:
            os.kill(running["pid"], signal.SIGKILL)
            return
        time.sleep(0.05)
    raise AssertionError(f"attempt {attempt} never started ({record})")


@pytest.mark.filterwarnings("ignore")
def test_a_killed_task_is_retried_then_reported_failed_and_the_rerun_trains_only_it(tmp_path: Path) -> None:
    output = tmp_path / "ray"
    scene = generated_scenes(BenchmarkConfig(quick=True, output=output))[0]  # one scene: half the trainings
    arguments = ("--scenes", str(scene), "--properties", "semantics", "--no-all-properties-model", "--retries", "1")
    victim = output / "runs" / "walkthrough_seed_0" / "ssnerf-semantics" / "ssnerf-lite" / "30-steps"
    process = driver(output, *arguments)
    kill_attempt(victim / "launcher.log.running", 1, process)  # retried: --retries 1
    kill_attempt(victim / "launcher.log.running", 2, process)  # past its retries: failed
    text = finished(process)
    assert "1 failed" in text

    log = (victim / "launcher.log").read_text()
    assert "attempt 1 on" in log and "attempt 2 on" in log and "attempt 3" not in log
    record = json.loads((victim / "launcher.log.failed.json").read_text())
    assert record["log"] == str(victim / "launcher.log") and "Worker" in record["error"]
    report = (output / "report.md").read_text()
    assert "## Failed runs" in report and f"walkthrough_seed_0 / ssnerf-semantics: {record['error']}" in report
    assert str(victim / "launcher.log") in report
    others = sorted(set((output / "runs").rglob("metrics.json")))
    assert len(others) == 1 and not (victim / "metrics.json").exists()  # the other model (the NeRF) is kept
    kept = {path: path.stat().st_mtime_ns for path in others}
    baselines = sorted((output / "runs").glob("walkthrough_seed_*/*-30-steps.json"))
    assert len(baselines) == 3  # the scene's three baselines (they need only the NeRF)

    text = finished(driver(output, *arguments))
    assert "1 of 5 runs to do" in text
    assert (victim / "metrics.json").is_file() and not (victim / "launcher.log.failed.json").exists()
    assert {path: path.stat().st_mtime_ns for path in others} == kept  # finished runs were not retrained
    assert "Failed runs" not in (output / "report.md").read_text()


@pytest.mark.filterwarnings("ignore")
def test_ctrl_c_cancels_the_tasks_and_keeps_the_finished_runs(tmp_path: Path) -> None:
    output = tmp_path / "ray"
    process = driver(output, "--properties", "semantics", "--no-all-properties-model")
    deadline = time.time() + 900
    while not list((output / "runs").rglob("metrics.json")):
        assert process.poll() is None and time.time() < deadline, "no run finished"
        time.sleep(0.2)
    process.send_signal(signal.SIGINT)
    text, _ = process.communicate(timeout=300)
    assert process.returncode != 0 and "stopped; finished runs are kept" in text
    finished_runs = list((output / "runs").rglob("metrics.json"))
    assert finished_runs and all(json.loads(path.read_text())["psnr"] > 0 for path in finished_runs)
    time.sleep(2)
    started = [json.loads(path.read_text())["pid"] for path in (output / "runs").rglob("*.running")]
    assert started  # some run was still training when Ctrl-C came
    assert not [pid for pid in started if Path(f"/proc/{pid}").exists()]  # its worker was stopped with the driver
    assert not (output / "report.md").exists()  # no half report: a new call resumes and writes it
