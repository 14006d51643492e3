"""The GPU check (`scripts/gpu_check.sh`): on a machine with one NVIDIA GPU, in a few minutes, run the CUDA-only tests
and train `ssnerf-lite` and `ssnerf` with every property on a 640x480 generated scene, then print one JSON line:
per method rays/s, GPU memory peak, PSNR and mIoU, plus the tests' outcome.

Without CUDA it says so, prints the plan as JSON with `"dry_run": true`, and exits 0 (CI runs that).
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List

import torch
import tyro

from ssnerf_method.properties import OPTIONAL_PROPERTIES


@dataclass
class GpuCheckConfig:
    """Check SS-NeRF on a CUDA GPU and print the numbers as one JSON line."""

    output: Path = Path("reports/gpu_check")
    """Scene, runs and the JSON (`gpu_check.json`)."""
    width: int = 640
    """Generated scene's image width."""
    height: int = 480
    """Generated scene's image height."""
    num_frames: int = 30
    """Frames of the generated scene (every 5th is a test view)."""
    steps_lite: int = 1000
    """Training steps of `ssnerf-lite`."""
    steps_ssnerf: int = 1000
    """Training steps of `ssnerf`."""
    dry_run: bool = False
    """Print the plan and exit, even with a GPU."""


def plan(config: GpuCheckConfig) -> List[str]:
    return [
        f"{sys.executable} -m pytest -q -m cuda tests/test_cuda.py  (nerfacc vs torch weights on CUDA; a CUDA step of "
        "both methods)",
        f"ssnerf-make-scene {config.output / 'scene'} --width {config.width} --height {config.height} "
        f"--num-frames {config.num_frames}",
        f"train ssnerf-lite, all properties, {config.steps_lite} steps; ns-eval on the test views",
        f"train ssnerf, all properties, {config.steps_ssnerf} steps; ns-eval on the test views",
        f"print one JSON line (also {config.output / 'gpu_check.json'}): per method rays/s, GPU memory peak (MiB), "
        "PSNR, mIoU, train seconds",
    ]


def train_and_measure(config: GpuCheckConfig, scene: Path, method: str, steps: int) -> Dict[str, float]:
    from ssnerf_method.experiments.benchmark import BenchmarkConfig, ModelRun, SceneBenchmark

    bench = SceneBenchmark(BenchmarkConfig(scenes=(scene,), method=method, output=config.output, steps=steps),  # type: ignore
                           scene, "scene")
    torch.cuda.reset_peak_memory_stats()
    metrics = bench.train_and_score(ModelRun("all", OPTIONAL_PROPERTIES))
    rays = bench.trainer_config(ModelRun("all", OPTIONAL_PROPERTIES)).pipeline.datamanager.train_num_rays_per_batch  # type: ignore
    seconds = metrics.get("train_seconds") or float("nan")
    return {
        "steps": steps,
        "train_seconds": seconds,
        "rays_per_second": round(steps * rays / seconds, 1),
        "gpu_memory_peak_mib": round(torch.cuda.max_memory_allocated() / 2**20, 1),
        "psnr": round(metrics["psnr"], 3),
        "semantics_miou": round(metrics.get("semantics_miou", float("nan")), 4),
    }


def main(config: GpuCheckConfig) -> Dict:
    steps = plan(config)
    if config.dry_run or not torch.cuda.is_available():
        reason = "--dry-run" if config.dry_run else "no CUDA GPU here (torch.cuda.is_available() is False)"
        result = {"dry_run": True, "reason": reason, "plan": steps}
        print(json.dumps(result))
        return result
    from ssnerf_method.scene.make_scene import MakeSceneConfig, make_scene

    start = time.time()
    result: Dict = {"dry_run": False, "device": torch.cuda.get_device_name(0), "torch": torch.__version__}
    tests = subprocess.run([sys.executable, "-m", "pytest", "-q", "-m", "cuda", "tests/test_cuda.py"],
                           capture_output=True, text=True)
    result["cuda_tests"] = {"exit_status": tests.returncode, "summary": (tests.stdout.strip().splitlines() or [""])[-1]}
    scene = config.output / "scene"
    if not (scene / "transforms.json").is_file():
        make_scene(MakeSceneConfig(output_dir=scene, width=config.width, height=config.height,
                                   num_frames=config.num_frames))
    result["scene_seconds"] = round(time.time() - start, 1)
    for method, count in (("ssnerf-lite", config.steps_lite), ("ssnerf", config.steps_ssnerf)):
        result[method] = train_and_measure(config, scene, method, count)
    result["total_seconds"] = round(time.time() - start, 1)
    config.output.mkdir(parents=True, exist_ok=True)
    (config.output / "gpu_check.json").write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result))
    return result


def entrypoint() -> None:
    main(tyro.cli(GpuCheckConfig))


if __name__ == "__main__":
    entrypoint()
