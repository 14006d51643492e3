"""How close normals made by `ssnerf-label --depth-from` come to normals made from the true depth.

    python -m benchmarks.benchmark_depth_from [--output reports/depth_from] [--steps 2000] \
        [--depth-smoothness 0.1] [--depth-from-scale 0.25] [--depth-from-smoothing 0.1] [--properties edges keypoints]

1. Generates the benchmark's walkthrough scene (`BENCHMARK_SCENE`, seed 0) and a depth-less copy of it, `capture/`
   (images and poses only, as `ns-process-data` leaves a phone capture).
2. Trains an RGB-only `ssnerf-lite` on `capture/` for `--steps` as `ssnerf-label` trains its depth model (every
   frame unless `--no-every-frame`; `cli.label.depth_model_trainer`), with
   `--depth-smoothness` the `depth_smoothness` regulariser's `mult`; a run whose final checkpoint exists is reused.
   With `--properties` (those `ssnerf-label` makes from the images alone, edges and keypoints), the model trains on them
   too, labelled first in a copy, `capture_labelled/`.
3. Labels normals and shading twice with `ssnerf-label`'s engine: `truth/` from the scene's depth files, `rendered/`
   (a fresh copy of `capture/`) with `--depth-from` the model.
4. Prints and writes (`OUTPUT/depth_from.json`) the median and mean angle between the two normal maps over the pixels
   labelled in both, over every frame and per split (the model's training frames, the held-out ones), beside the
   angle a constant depth would give (every normal facing the camera); saves one held-out frame side by side
   (`OUTPUT/normals_<frame>.png`: image | normals from the true depth | from rendered depth | angle, 0-45 degrees).
"""

from __future__ import annotations

import json
import shutil
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional, Tuple

import cv2
import numpy as np
import tyro
from PIL import Image

from nerfstudio.utils.rich_utils import CONSOLE

from ssnerf_method.cli.label import depth_model_trainer
from ssnerf_method.data.io import write_json_atomic
from ssnerf_method.data.transforms import load_transforms
from ssnerf_method.engine.trainer import train_in_process
from ssnerf_method.experiments.benchmark import BENCHMARK_SCENE
from ssnerf_method.label_makers.encoding import decode_normals
from ssnerf_method.label_tool.label_dataset import LabelDatasetBase, LabelDatasetConfig, label_dataset
from ssnerf_method.properties import OPTIONAL_PROPERTIES, REGISTRY, labelled_properties
from ssnerf_method.scene.make_scene import MakeSceneConfig, make_scene

METHOD = "ssnerf-lite"


@dataclass
class BenchmarkDepthFromConfig:
    """Normals from `--depth-from` an RGB-only ssnerf-lite against normals from the true depth."""

    output: Path = Path("reports/depth_from")
    """Folder for the scene, the model, the labelled copies and the results (reused: the model is trained once)."""
    steps: int = LabelDatasetBase.depth_model_steps
    """Training steps of the RGB-only ssnerf-lite (default: ssnerf-label's --depth-model-steps)."""
    depth_smoothness: float = 0.1
    """The model's `--pipeline.model.regularisers.depth-smoothness.mult` (0: off, a plain RGB-only run)."""
    depth_from_scale: float = LabelDatasetBase.depth_from_scale
    """`ssnerf-label --depth-from-scale`: resolution of the rendered depth (default: ssnerf-label's)."""
    depth_from_smoothing: float = LabelDatasetBase.depth_from_smoothing
    """`ssnerf-label --depth-from-smoothing`: guided-filter radius over the normals, as a fraction of the image's
    shorter side (default: ssnerf-label's; 0 = none)."""
    properties: Tuple[str, ...] = ()
    """Properties the model trains on beside RGB, labelled from the images alone by `ssnerf-label` (edges,
    keypoints: what a capture without depth has); default none, an RGB-only model."""
    every_frame: bool = True
    """Train on every frame, the held-out ones too, as `ssnerf-label`'s depth model does (a labeller sees each image,
    as a depth sensor would); `--no-every-frame`: on the training split only."""
    seed: int = 0
    """Scene seed."""
    width: Optional[int] = None
    """Scene size (default: the benchmark's, 128x96, 50 frames); smaller for a smoke run."""
    height: Optional[int] = None
    num_frames: Optional[int] = None

    def __post_init__(self) -> None:
        """A property that needs more than the images ends the run here, before any scene is generated."""
        from_images = [spec.name for spec in labelled_properties() if set(spec.label_maker.reads) <= {"rgb"}]
        unknown = sorted(set(self.properties) - set(from_images))
        if unknown:
            raise SystemExit(f"--properties: {', '.join(unknown)} cannot be labelled from the images alone; choose "
                             f"among {', '.join(from_images)}")

    @property
    def model_name(self) -> str:
        """What the model learns: "rgb-only", or e.g. "rgb+edges+keypoints", then "-smooth0.1" with
        `--depth-smoothness` (its run folder and the printed line)."""
        name = "+".join(("rgb", *self.properties)) if self.properties else "rgb-only"
        name = f"{name}-every-frame" if self.every_frame else name
        return f"{name}-smooth{self.depth_smoothness:g}" if self.depth_smoothness > 0 else name


def images_only(scene: Path, target: Path, keep_depth: bool) -> Path:
    """A fresh copy of `scene` whose transforms list images, poses (and depth, if kept) and no labels."""
    shutil.rmtree(target, ignore_errors=True)
    shutil.copytree(scene, target)
    meta = json.loads((target / "transforms.json").read_text())
    for frame in meta["frames"]:
        for name in OPTIONAL_PROPERTIES:
            frame.pop(REGISTRY[name].file_key, None)
        if not keep_depth:
            frame.pop("depth_file_path", None)
    for key in ("semantic_classes", "semantic_colors"):
        meta.pop(key, None)
    write_json_atomic(target / "transforms.json", meta)
    return target


def train(config: BenchmarkDepthFromConfig, capture: Path) -> Dict:
    """Train (or reuse) the model (RGB, plus `--properties`) as `ssnerf-label` trains its depth model; returns its
    config.yml path and training seconds (None when reused)."""
    trainer = depth_model_trainer(load_transforms(capture), config.output / "runs", config.steps, config.every_frame)
    trainer.pipeline.model.properties = config.properties  # type: ignore[attr-defined]
    trainer.pipeline.model.regularisers["depth_smoothness"].mult = config.depth_smoothness  # type: ignore[attr-defined]
    trainer.experiment_name = config.model_name
    config_path = trainer.get_base_dir() / "config.yml"
    checkpoint = trainer.get_checkpoint_dir() / f"step-{config.steps - 1:09d}.ckpt"
    seconds = None
    if not checkpoint.is_file():
        CONSOLE.rule(f"Training {config.model_name} {METHOD} for {config.steps} steps on {capture}")
        start = time.time()
        train_in_process(trainer)
        seconds = round(time.time() - start, 1)
    return {"config": config_path, "train_seconds": seconds}


def label(data: Path, properties: Tuple[str, ...] = ("normals", "shading"), **options) -> float:
    """Label `properties` of `data` in place (normals and shading unless told); returns the seconds it took."""
    start = time.time()
    switches = {spec.name: spec.name in properties for spec in labelled_properties()}
    config = LabelDatasetConfig(data=data, **switches, **options)
    label_dataset(config, load_transforms(data))
    return round(time.time() - start, 1)


def normals_of(data: Path, frame: Dict) -> np.ndarray:
    """(H, W, 3) unit normals of a labelled frame, NaN where unlabelled."""
    encoded = np.asarray(Image.open(data / frame["normals_file_path"]))
    normals = decode_normals(encoded[..., :3].astype(np.float64) / 255.0)
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    if encoded.shape[-1] == 4:
        normals[encoded[..., 3] == 0] = np.nan
    return normals


def angle_degrees(first: np.ndarray, second: np.ndarray) -> np.ndarray:
    cosine = np.clip(np.einsum("...c,...c->...", first, second), -1.0, 1.0)
    return np.degrees(np.arccos(cosine))


def summary(angles: List[np.ndarray]) -> Dict[str, float]:
    values = np.concatenate([angle[np.isfinite(angle)] for angle in angles]) if angles else np.zeros(0)
    return {"median_deg": round(float(np.median(values)), 2), "mean_deg": round(float(np.mean(values)), 2),
            "pixels": int(values.size)}


def side_by_side(path: Path, rgb: np.ndarray, truth: np.ndarray, rendered: np.ndarray, angle: np.ndarray) -> None:
    """image | normals from the true depth | from rendered depth | angle between them (0-45 degrees, grey = none)."""

    def shown(normals: np.ndarray) -> np.ndarray:
        image = np.nan_to_num((normals + 1.0) / 2.0 * 255.0, nan=128.0)
        return image.round().astype(np.uint8)

    heat = cv2.applyColorMap((np.clip(np.nan_to_num(angle, nan=0.0) / 45.0, 0, 1) * 255).astype(np.uint8),
                             cv2.COLORMAP_INFERNO)[..., ::-1]
    heat[~np.isfinite(angle)] = 128
    row = np.concatenate([rgb[..., :3], shown(truth), shown(rendered), heat], axis=1)
    Image.fromarray(row).resize((row.shape[1] * 4, row.shape[0] * 4), Image.NEAREST).save(path)


def main(config: BenchmarkDepthFromConfig) -> Dict:
    output = config.output
    output.mkdir(parents=True, exist_ok=True)
    scene = output / f"scene_seed_{config.seed}"
    size = {key: value for key, value in (("width", config.width), ("height", config.height),
                                          ("num_frames", config.num_frames)) if value is not None}
    if not (scene / "transforms.json").is_file():
        make_scene(MakeSceneConfig(output_dir=scene, seed=config.seed, overwrite=True, path_frames=0,  # type: ignore
                                   **BENCHMARK_SCENE, **size))
    capture = output / "capture"
    if not (capture / "transforms.json").is_file():
        images_only(scene, capture, keep_depth=False)
    training = capture
    if config.properties:
        training = output / "capture_labelled"
        if not (training / "transforms.json").is_file():
            label(images_only(capture, training, keep_depth=False), config.properties, workers=2)
    run = train(config, training)

    truth = images_only(scene, output / "truth", keep_depth=True)
    rendered = images_only(capture, output / "rendered", keep_depth=False)
    truth_seconds = label(truth, workers=2)
    rendered_seconds = label(rendered, workers=2, depth_from=run["config"], depth_from_scale=config.depth_from_scale,
                             depth_from_smoothing=config.depth_from_smoothing)

    truth_frames = json.loads((truth / "transforms.json").read_text())["frames"]
    meta = json.loads((rendered / "transforms.json").read_text())
    held_out = set(json.loads((scene / "transforms.json").read_text()).get("test_filenames", []))
    angles: Dict[str, List[np.ndarray]] = {"all": [], "train": [], "test": []}
    constant: List[np.ndarray] = []
    shown = None
    for true_frame, frame in zip(truth_frames, meta["frames"]):
        true_normals, normals = normals_of(truth, true_frame), normals_of(rendered, frame)
        angle = angle_degrees(true_normals, normals)  # NaN unless labelled in both
        split = "test" if frame["file_path"] in held_out else "train"
        angles["all"].append(angle)
        angles[split].append(angle)
        constant.append(angle_degrees(true_normals, np.array([0.0, 0.0, 1.0]))[np.isfinite(angle)])
        if shown is None and split == "test":
            shown = Path(frame["file_path"]).stem
            rgb = np.asarray(Image.open(rendered / frame["file_path"]))
            side_by_side(output / f"normals_{shown}.png", rgb, true_normals, normals, angle)

    result = {
        "command": " ".join(["python -m benchmarks.benchmark_depth_from", *sys.argv[1:]]),
        "scene": {"seed": config.seed, **BENCHMARK_SCENE, **size, "frames": len(meta["frames"]),
                  "held_out": len(held_out)},
        "model": {"method": METHOD, "properties": list(config.properties), "steps": config.steps,
                  "every_frame": config.every_frame,
                  "depth_smoothness_mult": config.depth_smoothness,
                  "config": str(run["config"]), "train_seconds": run["train_seconds"]},
        "depth_from_scale": config.depth_from_scale,
        "depth_from_smoothing": config.depth_from_smoothing,
        "label_seconds": {"true_depth": truth_seconds, "depth_from": rendered_seconds},
        "angle": {split: summary(values) for split, values in angles.items()},
        "constant_depth_angle": summary(constant),
        "figure": str(output / f"normals_{shown}.png") if shown else None,
    }
    write_json_atomic(output / "depth_from.json", result)
    CONSOLE.print(f"Normals from --depth-from ({config.steps}-step {config.model_name} {METHOD}, depth at "
                  f"{config.depth_from_scale:g}x, smoothing {config.depth_from_smoothing:g}) against normals from the "
                  "true depth, over pixels labelled in both:")
    for split, values in result["angle"].items():
        CONSOLE.print(f"  {split:5s} frames: median {values['median_deg']:.2f} deg, mean {values['mean_deg']:.2f} deg "
                      f"({values['pixels']} pixels)")
    CONSOLE.print(f"  a constant depth would give: median {result['constant_depth_angle']['median_deg']:.2f} deg")
    CONSOLE.print(f"Wrote {output / 'depth_from.json'}")
    return result


def entrypoint() -> None:
    main(tyro.cli(BenchmarkDepthFromConfig))


if __name__ == "__main__":
    entrypoint()
