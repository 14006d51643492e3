"""Time dataset validation against loading the same dataset without it.

    python -m benchmarks.benchmark_validation [--num-frames 300] [--width 1920] [--height 1080]

Writes a synthetic dataset of that size (once; kept in `--data-dir`): JPEG images, 16-bit depth and every property
label as PNGs, smooth shapes so that the files compress as real ones do. Then, one after the other on an idle machine:

- validation alone, headers only (the dataparser's default) and with the pixel checks (`ssnerf-check`'s);
- nerfstudio's dataparser for the train and test splits without validation, then decoding every training item through
  `SSNeRFDataset` (what the datamanager's cache does before step 0): "loading without validation";
- the same with the dataparser's validation (headers), which checks the label pixels as the items are decoded.

One untimed load first warms the imports and the file cache; then each measurement is the best of `--repeats` runs,
the two loads interleaved. Times are seconds of wall clock; the overhead is validation's share of loading.
"""

from __future__ import annotations

import json
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import tyro
from rich.table import Table

from nerfstudio.utils.rich_utils import CONSOLE

from ssnerf_method.data.dataparser import SSNeRFDataParser, SSNeRFDataParserConfig
from ssnerf_method.data.dataset import SSNeRFDataset
from ssnerf_method.data.validate import validate_dataset
from ssnerf_method.label_makers.encoding import encode_normals, to_uint8
from ssnerf_method.properties import REGISTRY


@dataclass
class BenchmarkValidationConfig:
    """Seconds of validation and of loading for one synthetic dataset."""

    num_frames: int = 300
    width: int = 1920
    height: int = 1080
    data_dir: Path = Path("reports/validation_benchmark/data")
    """Where the synthetic dataset is written (reused when it already has the requested size)."""
    workers: int = 4
    """Validation threads (the dataparser's default)."""
    repeats: int = 2
    """Timed runs of each measurement (the best is reported), after one untimed warm-up load."""


def write_frame(root: Path, index: int, width: int, height: int) -> dict:
    """One frame: a few shaded rectangles over a gradient, and labels that agree with them."""
    rng = np.random.default_rng(index)
    ids = np.zeros((height, width), np.uint8)
    for label in range(1, 6):
        x, y = rng.integers(0, width - width // 4), rng.integers(0, height - height // 4)
        ids[y:y + height // 4, x:x + width // 4] = label
    rows = np.linspace(0.0, 1.0, height, dtype=np.float32)[:, None]
    colours = rng.uniform(0.2, 0.9, (6, 3)).astype(np.float32)
    rgb = colours[ids] * (0.7 + 0.3 * rows)[..., None]
    normal_table = np.array([[0, 0, 1], [1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0], [0.6, 0, 0.8]], np.float32)
    normals = to_uint8(encode_normals(normal_table[ids]))
    edges = (cv2.Canny(ids * 40, 10, 20) > 0).astype(np.uint8) * 255
    name = f"frame_{index:05d}"
    files = {
        "file_path": (f"images/{name}.jpg", cv2.cvtColor((rgb * 255).astype(np.uint8), cv2.COLOR_RGB2BGR)),
        "depth_file_path": (f"depth/{name}.png", (1000 + 2000 * rows * np.ones((1, width))).astype(np.uint16)),
        REGISTRY["semantics"].file_key: (f"semantics/{name}.png", ids),
        REGISTRY["normals"].file_key: (f"normals/{name}.png", cv2.cvtColor(normals, cv2.COLOR_RGB2BGR)),
        REGISTRY["shading"].file_key: (f"shading/{name}.png", (rgb.mean(axis=-1) * 255).astype(np.uint8)),
        REGISTRY["keypoints"].file_key: (f"keypoints/{name}.png", cv2.GaussianBlur(edges, (0, 0), 3)),
        REGISTRY["edges"].file_key: (f"edges/{name}.png", edges),
    }
    for relative, image in files.values():
        (root / relative).parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(root / relative), image)
    angle = 2 * np.pi * index / 300
    pose = np.eye(4)
    pose[:3, 3] = [np.cos(angle), np.sin(angle), 0.3]
    return {"transform_matrix": pose.tolist(), **{key: relative for key, (relative, _) in files.items()}}


def synthetic_dataset(config: BenchmarkValidationConfig) -> Path:
    root = config.data_dir
    path = root / "transforms.json"
    if path.is_file():
        meta = json.loads(path.read_text())
        if len(meta["frames"]) == config.num_frames and (meta["w"], meta["h"]) == (config.width, config.height):
            return root
    root.mkdir(parents=True, exist_ok=True)
    with ThreadPoolExecutor() as pool:
        frames = list(pool.map(lambda index: write_frame(root, index, config.width, config.height),
                               range(config.num_frames)))
    meta = {
        "camera_model": "OPENCV", "fl_x": 0.8 * config.width, "fl_y": 0.8 * config.width, "cx": config.width / 2,
        "cy": config.height / 2, "w": config.width, "h": config.height,
        "semantic_classes": [f"class_{index}" for index in range(6)], "frames": frames,
    }
    path.write_text(json.dumps(meta))
    return root


def timed(function) -> float:
    start = time.perf_counter()
    function()
    return time.perf_counter() - start


def load(data: Path, validate: bool) -> float:
    """Dataparser (train and test splits), then every training item decoded as the datamanager's cache does."""

    def run() -> None:
        parser = SSNeRFDataParserConfig(data=data).setup()
        assert isinstance(parser, SSNeRFDataParser)
        parser._validated = not validate
        dataset = SSNeRFDataset(parser.get_dataparser_outputs("train"))
        parser.get_dataparser_outputs("test")
        with ThreadPoolExecutor() as pool:  # nerfstudio's cache loads items on a default thread pool too
            for _ in pool.map(dataset.__getitem__, range(len(dataset))):
                pass

    return timed(run)


def main(config: BenchmarkValidationConfig) -> None:
    start = time.perf_counter()
    data = synthetic_dataset(config)
    CONSOLE.print(f"dataset: {data} ({config.num_frames} frames, {config.width}x{config.height}; "
                  f"{time.perf_counter() - start:.0f} s to make or find)")
    load(data, validate=False)  # warm-up: imports and the file cache, so every timed run reads from memory alike
    headers = min(timed(lambda: validate_dataset(data, contents=False, workers=config.workers).raise_if_faulty())
                  for _ in range(config.repeats))
    contents = min(timed(lambda: validate_dataset(data, contents=True, workers=config.workers).raise_if_faulty())
                   for _ in range(config.repeats))
    without, with_validation = float("inf"), float("inf")
    for _ in range(config.repeats):  # interleaved, best of `repeats` each
        without = min(without, load(data, validate=False))
        with_validation = min(with_validation, load(data, validate=True))
    table = Table(title=f"Validation vs loading, {config.num_frames} frames at {config.width}x{config.height}")
    for column in ("what", "seconds", "share of loading"):
        table.add_column(column)
    table.add_row("validation, headers only (the dataparser's)", f"{headers:.2f}", f"{headers / without:.1%}")
    table.add_row("validation with pixel checks (ssnerf-check's)", f"{contents:.2f}", f"{contents / without:.1%}")
    table.add_row("loading without validation (parser + every item decoded)", f"{without:.2f}", "100%")
    table.add_row("loading with the dataparser's validation", f"{with_validation:.2f}",
                  f"{with_validation / without:.1%}")
    CONSOLE.print(table)


def entrypoint() -> None:
    main(tyro.cli(BenchmarkValidationConfig))


if __name__ == "__main__":
    entrypoint()
