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


TRACE = """
import json, sys
from importlib.metadata import packages_distributions
sys.path.insert(0, "tests")
from conftest import write_tiny_dataset
from test_training import lite_config, train
from nerfstudio.utils.eval_utils import eval_setup
write_tiny_dataset(OUT / "data")
trainer, _, _ = train(lite_config(OUT / "data", OUT / "outputs", iterations=2))
eval_setup(next((OUT / "outputs").rglob("config.yml")), test_mode="test")[1].get_average_eval_image_metrics()
owners = packages_distributions()
print(json.dumps(sorted({d for m in list(sys.modules) for d in owners.get(m.split(".")[0], [])})))
"""


def test_the_gpu_carry_wheels_cover_what_a_training_imports_beyond_the_image(tmp_path: Path) -> None:
    """What a tiny training and its evaluation import is on the lent machine's image or among the wheels
    `scripts/gpu_carry.py` downloads for it (a new runtime dependency that the image lacks fails here, not there)."""
    import sys

    sys.path.insert(0, str(ROOT / "scripts"))
    import gpu_carry

    script = f"from pathlib import Path\nOUT = Path({str(tmp_path)!r})\n" + TRACE
    result = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True, timeout=600,
                            env={**__import__("os").environ, "OMP_NUM_THREADS": "1"})
    assert result.returncode == 0, result.stderr[-2000:]
    imported = json.loads(result.stdout.strip().splitlines()[-1])

    def normal(name: str) -> str:
        return name.lower().replace("_", "-")

    carried = {normal(name) for name in gpu_carry.MISSING_ON_THE_IMAGE}
    allowed = carried | {normal(name) for name in gpu_carry.IMAGE_HAS} | {"ssnerf-method",
                                                                         "opencv-contrib-python-headless"}
    assert "nerfstudio" in imported and "nerfacc" in imported
    assert sorted(normal(name) for name in imported if normal(name) not in allowed) == []
    pins = gpu_carry.pins()
    assert "nerfstudio==1.1.5" in pins and all("==" in pin for pin in pins)  # every one is installed here
