"""The GPU check's dry run (CI has no GPU): `scripts/gpu_check.sh` prints its plan as one JSON line and exits 0."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

ROOT = Path(__file__).parents[1]


def test_gpu_check_dry_run_prints_its_plan() -> None:
    result = subprocess.run([ROOT / "scripts" / "gpu_check.sh", "--dry-run", "--steps-lite", "7"], cwd=ROOT,
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout.strip().splitlines()[-1])
    assert report["dry_run"] is True
    assert any("pytest" in step and "cuda" in step for step in report["plan"])
    assert any("ssnerf-lite" in step and "7 steps" in step for step in report["plan"])
    assert any("640 --height 480" in step for step in report["plan"])
