"""Where the benchmark's and the studies' trainings run: `local` (in this process, as the report is written) or `ray`
(every unfinished `Job` a Ray task before the report, which then only reads the results; Ray is imported only then).
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import socket
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Dict, Iterator, List, Literal, Optional, Sequence, Tuple

from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from nerfstudio.utils.rich_utils import CONSOLE

from ssnerf_method.atomic import write_text_atomic
from ssnerf_method.errors import UserError

RUNNING_SUFFIX = ".running"
"""Next to a job's log while a worker runs it: the worker's host, pid and attempt (JSON)."""
FAILED_SUFFIX = ".failed.json"
"""Next to a job's log once it has failed for good: the error and the log's path."""


@dataclass(frozen=True)
class Job:
    """One unit of the benchmark's or a study's work whose result is a file under the output folder."""

    key: str
    """Unique name (the result's folder relative to the output folder): two jobs with one key are one job."""
    work: Callable[[], Any]
    """What to run (picklable: a module-level function with its arguments bound)."""
    result: Path
    """The file that exists once the job has finished (reused, as every run is)."""
    log: Path
    """Where a Ray worker writes the job's console output."""
    after: Tuple[str, ...] = ()
    """Keys of the jobs whose results this one reads."""

    @property
    def done(self) -> bool:
        return self.result.is_file()

    @property
    def running_file(self) -> Path:
        return self.log.with_name(self.log.name + RUNNING_SUFFIX)

    @property
    def failed_file(self) -> Path:
        return self.log.with_name(self.log.name + FAILED_SUFFIX)


def failure(log: Path) -> Optional[Dict[str, str]]:
    """What a failed job left next to its log ({"error", "log"}), or None if it has not failed."""
    path = log.with_name(log.name + FAILED_SUFFIX)
    return json.loads(path.read_text()) if path.is_file() else None


@contextlib.contextmanager
def exclusive(lock: Path) -> Iterator[None]:
    """Hold an exclusive lock on `lock`, so two processes never train one run at once (the second reuses the result)."""
    lock.parent.mkdir(parents=True, exist_ok=True)
    with lock.open("a") as handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX)
        except OSError as error:  # a filesystem without locks (some NFS mounts): run unguarded
            CONSOLE.print(f"[yellow]{lock}: no file lock on this filesystem ({error}); two commands sharing this "
                          "--output could train this run at once")
            yield
            return
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def ordered(jobs: Sequence[Job]) -> List[Job]:
    """`jobs` without repeated keys, each after the jobs it needs (dependencies on unlisted keys are ignored)."""
    unique: Dict[str, Job] = {}
    for job in jobs:
        unique.setdefault(job.key, job)
    placed: Dict[str, Job] = {}

    def place(job: Job, chain: Tuple[str, ...]) -> None:
        if job.key in placed:
            return
        if job.key in chain:
            raise ValueError(f"jobs depend on each other in a cycle: {' -> '.join((*chain, job.key))}")
        for key in job.after:
            if key in unique:
                place(unique[key], (*chain, job.key))
        placed[job.key] = job

    for job in unique.values():
        place(job, ())
    return list(placed.values())


@dataclass
class LauncherOptions:
    """Where the trainings of `ssnerf-benchmark` and `ssnerf-study` run (their configs inherit these flags)."""

    launcher: Literal["local", "ray"] = "local"
    """`local`: one training after another in this process. `ray`: each a Ray task (`pip install -e .[cluster]`)."""
    ray_address: Optional[str] = None
    """Ray cluster to join (e.g. `auto`); default: a local instance. Nodes need the plugin and --output's path."""
    cpus_per_run: float = 1.0
    """CPUs Ray reserves for each run (torch uses that many threads)."""
    gpus_per_run: float = 0.0
    """GPUs Ray reserves for each run (1 for `ssnerf` on a GPU cluster)."""
    retries: int = 2
    """Times Ray retries a run whose worker died (killed, out of memory) before it is reported as failed."""


def launch(settings: LauncherOptions, jobs: Sequence[Job]) -> Dict[str, Dict[str, str]]:
    """Run the unfinished `jobs` with Ray; returns key -> failure. `local` runs nothing: the report step trains."""
    if settings.launcher == "local":
        return {}
    return RayLauncher(settings).run(ordered(jobs))


def run_job(job: Job, *_needed: Any) -> None:
    """A job as a Ray worker runs it: fds 1 and 2 into its log and a `.running` record; `_needed` makes Ray wait."""
    import torch

    threads = os.environ.get("OMP_NUM_THREADS")  # Ray sets it to the task's CPUs
    if threads and threads.isdigit():
        torch.set_num_threads(max(1, int(threads)))
    job.log.parent.mkdir(parents=True, exist_ok=True)
    attempt = 1
    if job.running_file.is_file():  # a worker died running it: this is a retry
        with contextlib.suppress(ValueError, KeyError):
            attempt = json.loads(job.running_file.read_text())["attempt"] + 1
    sys.stdout.flush()
    sys.stderr.flush()
    saved = os.dup(1), os.dup(2)
    with job.log.open("a") as log:
        # the log names the attempt before the record does, so a reader of the record finds it even if the worker dies
        log.write(f"\n=== {job.key}: attempt {attempt} on {socket.gethostname()}, pid {os.getpid()}, "
                  f"{time.strftime('%Y-%m-%d %H:%M:%S')} ===\n")
        log.flush()
        write_text_atomic(job.running_file, json.dumps({"host": socket.gethostname(), "pid": os.getpid(),
                                                        "attempt": attempt}))
        os.dup2(log.fileno(), 1)
        os.dup2(log.fileno(), 2)
        try:
            job.work()
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            for descriptor in saved:
                os.close(descriptor)
    job.running_file.unlink(missing_ok=True)


class RayLauncher:
    """Runs jobs as Ray tasks with declared resources and bounded retries, with one progress display."""

    def __init__(self, settings: LauncherOptions) -> None:
        self.settings = settings

    def run(self, jobs: List[Job]) -> Dict[str, Dict[str, str]]:
        todo = [job for job in jobs if not job.done]
        if not todo:
            CONSOLE.print(f"[dim]launcher ray: all {len(jobs)} runs done earlier, nothing to train")
            return {}
        try:
            import ray
        except ImportError as error:
            raise UserError("--launcher ray needs Ray: pip install -e '.[cluster]' (or pip install ray)") from error
        for job in todo:  # a new attempt: an earlier call's failure or dead worker's record is stale
            job.failed_file.unlink(missing_ok=True)
            job.running_file.unlink(missing_ok=True)
        started = not ray.is_initialized()
        if started:
            ray.init(address=self.settings.ray_address, log_to_driver=False, include_dashboard=False,
                     configure_logging=False)
        try:
            return self.supervise(ray, jobs, todo)
        finally:
            if started:
                ray.shutdown()

    def supervise(self, ray: Any, jobs: List[Job], todo: List[Job]) -> Dict[str, Dict[str, str]]:
        task = ray.remote(run_job).options(num_cpus=self.settings.cpus_per_run, num_gpus=self.settings.gpus_per_run,
                                           max_retries=self.settings.retries)
        by_key = {job.key: job for job in todo}
        refs: Dict[str, Any] = {}
        for job in todo:  # in dependency order, so the refs a job needs exist
            needed = [refs[key] for key in job.after if key in refs]
            refs[job.key] = task.remote(job, *needed)
        owner = {ref: key for key, ref in refs.items()}
        pending = list(refs.values())
        failures: Dict[str, Dict[str, str]] = {}
        resources = f"{self.settings.cpus_per_run:g} CPU, {self.settings.gpus_per_run:g} GPU per run"
        CONSOLE.print(f"launcher ray: {len(todo)} of {len(jobs)} runs to do ({resources}, "
                      f"cluster {ray.cluster_resources().get('CPU', 0):g} CPU / "
                      f"{ray.cluster_resources().get('GPU', 0):g} GPU); logs beside each run")
        columns = (TextColumn("[bold]runs"), BarColumn(), MofNCompleteColumn(), TextColumn("{task.fields[state]}"),
                   TimeElapsedColumn())
        try:
            with Progress(*columns, console=CONSOLE) as progress:
                bar = progress.add_task("runs", total=len(todo), state="")
                while pending:
                    finished, pending = ray.wait(pending, num_returns=1, timeout=1.0)
                    for ref in finished:
                        key = owner[ref]
                        try:
                            ray.get(ref)
                        except Exception as error:  # noqa: BLE001 - any failure of a task is reported, not raised
                            failures[key] = self.record_failure(by_key[key], error)
                            CONSOLE.print(f"[red]{key}: failed ({failures[key]['error']}); log {by_key[key].log}")
                    running = sum(by_key[owner[ref]].running_file.is_file() for ref in pending)
                    progress.update(bar, completed=len(todo) - len(pending),
                                    state=f"{len(todo) - len(pending) - len(failures)} done, {running} running, "
                                          f"{len(failures)} failed")
        except KeyboardInterrupt:
            for ref in pending:
                ray.cancel(ref, force=True)
            CONSOLE.print("[yellow]launcher ray: stopped; finished runs are kept, a new call resumes the others")
            raise
        return failures

    @staticmethod
    def record_failure(job: Job, error: Exception) -> Dict[str, str]:
        """Leave `<log>.failed.json` (the report reads it) and return it."""
        words = str(error).strip().splitlines()
        record = {"error": f"{type(error).__name__}: {words[-1] if words else ''}"[:300], "log": str(job.log)}
        job.log.parent.mkdir(parents=True, exist_ok=True)
        write_text_atomic(job.failed_file, json.dumps(record, indent=2))
        job.running_file.unlink(missing_ok=True)
        return record
