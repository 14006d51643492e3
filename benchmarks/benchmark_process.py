"""How long `ssnerf-process images` takes per stage, how many photos it poses and how close the poses are to the truth.

    python -m benchmarks.benchmark_process [--output reports/process] [--photos DIR] [--num-frames 50] \
        [--width 1920] [--height 1080] [--matching exhaustive]

Without `--photos`, the capture is the embedded room's loop rendered with surface grain (`ssnerf-make-scene --grain
0.3`) at half `--width`/`--height` and enlarged 2x to phone size as JPEG photos (the ray caster at full size takes
most of an hour on a CPU); its true poses give the pose errors after a similarity alignment. With `--photos` (a real
capture), the pose errors are left out. Writes `OUTPUT/process.json`.
"""

from __future__ import annotations

import json
import shutil
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, Optional

import cv2
import numpy as np
import tyro

from nerfstudio.utils.rich_utils import CONSOLE

from ssnerf_method.data.io import write_json_atomic
from ssnerf_method.evaluation.poses import pose_errors, poses_by_photo_order
from ssnerf_method.importers.photos import Matching, ProcessOptions, gather_photos, process_capture
from ssnerf_method.scene.make_scene import MakeSceneConfig, make_scene


@dataclass
class BenchmarkProcessConfig:
    """Time ssnerf-process's stages on a phone-sized capture and measure its poses."""

    output: Path = Path("reports/process")
    """Folder for the generated capture (reused), the dataset and process.json."""
    photos: Optional[Path] = None
    """A folder of real photos to time instead of the generated capture (no pose errors then)."""
    num_frames: int = 50
    width: int = 1920
    height: int = 1080
    matching: Matching = "exhaustive"
    max_image_size: int = ProcessOptions.max_image_size
    """Longest side SIFT sees (ssnerf-process's default; COLMAP's own is 3200)."""
    max_num_features: int = ProcessOptions.max_num_features
    """SIFT features kept per image."""


def generated_capture(config: BenchmarkProcessConfig) -> Path:
    """The grained room's loop as `--num-frames` JPEG photos of `--width` x `--height` (rendered at half size)."""
    scene, photos = config.output / "scene", config.output / "photos"
    if photos.is_dir() and len(list(photos.iterdir())) == config.num_frames:
        return photos
    make_scene(MakeSceneConfig(output_dir=scene, width=config.width // 2, height=config.height // 2,  # type: ignore
                               num_frames=config.num_frames, grain=0.3, overwrite=True, path_frames=0))
    shutil.rmtree(photos, ignore_errors=True)
    photos.mkdir()
    for image in sorted((scene / "images").iterdir()):
        pixels = cv2.resize(cv2.imread(str(image)), (config.width, config.height), interpolation=cv2.INTER_CUBIC)
        cv2.imwrite(str(photos / f"{image.stem}.jpg"), pixels, [cv2.IMWRITE_JPEG_QUALITY, 92])
    return photos


def main(config: BenchmarkProcessConfig) -> Dict:
    config.output.mkdir(parents=True, exist_ok=True)
    photos = config.photos or generated_capture(config)
    dataset = config.output / "dataset"
    start = time.perf_counter()
    options = ProcessOptions(matching=config.matching, max_image_size=config.max_image_size,
                             max_num_features=config.max_num_features, overwrite=True)
    report = process_capture(photos, dataset, options,
                             lambda images, observer: gather_photos(photos, images, observer))
    total = round(time.perf_counter() - start, 1)
    result: Dict = {
        "command": " ".join(["python -m benchmarks.benchmark_process", *sys.argv[1:]]),
        "photos": str(photos), "matching": config.matching, "max_image_size": config.max_image_size,
        "max_num_features": config.max_num_features,
        "num_images": report.num_images, "registered": len(report.registered),
        "unregistered": report.unregistered, "seconds": {**report.seconds, "total": total},
        "sparse_points": report.num_points, "reprojection_error_px": round(report.reprojection_error_px, 3),
    }
    if config.photos is None:
        errors = pose_errors(*poses_by_photo_order(config.output / "scene" / "transforms.json",
                                                   dataset / "transforms.json"))
        result["pose_errors"] = {"median_rotation_deg": round(float(np.median(errors.rotation_deg)), 3),
                                 "max_rotation_deg": round(float(errors.rotation_deg.max()), 3),
                                 "median_translation_share": round(float(np.median(errors.translation)), 4),
                                 "scene_size_m": round(errors.scene_size, 2)}
    write_json_atomic(config.output / "process.json", result)
    CONSOLE.print_json(json.dumps(result))
    return result


def entrypoint() -> None:
    main(tyro.cli(BenchmarkProcessConfig))


if __name__ == "__main__":
    entrypoint()
