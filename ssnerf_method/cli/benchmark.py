"""`ssnerf-benchmark`: the paper's Table 1 and Table 2-left (`experiments/benchmark.py`)."""

from __future__ import annotations

from ssnerf_method.errors import UserError, exit_with
from ssnerf_method.experiments import presets
from ssnerf_method.experiments.benchmark import BenchmarkConfig, run


def entrypoint() -> None:
    """Console script `ssnerf-benchmark` (`--preset configs/table1.yaml` reads its options from a file)."""
    try:
        run(presets.cli(BenchmarkConfig, "ssnerf-benchmark"))
    except UserError as err:
        exit_with(err, "ssnerf-benchmark")


if __name__ == "__main__":
    entrypoint()
