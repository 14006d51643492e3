"""`ssnerf-study propagation`: how little semantic labelling is enough.

It trains the semantics SS-NeRF on copies of each scene that keep k densely labelled frames (`--frames`), c clicks
per class per frame (`--pixels`), or those clicks grown over image segments, and scores it (mIoU) on the test and the
unlabelled training views beside baselines from the same labels: the Heuristic, the nearest labelled frame and the
nearest labelled pixel in 3D (what nearness alone gives), with the labels' mIoU ceiling and `BOUND`.

The copies (`OUTPUT/propagation/`) list every frame of the scene, so nerfstudio orients and scales poses alike.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Dict, List, Literal, Optional, Tuple

import numpy as np
import torch
from PIL import Image
from torch import Tensor

from nerfstudio.pipelines.base_pipeline import Pipeline
from nerfstudio.utils.rich_utils import CONSOLE

from ssnerf_method.atomic import write_text_atomic
from ssnerf_method.data.dataparser import SSNeRFDataParserConfig
from ssnerf_method.data.dataset import SSNeRFDataset
from ssnerf_method.data.io import StagedOutputFolder
from ssnerf_method.data.transforms import load_transforms
from ssnerf_method.evaluation.heuristic import (
    HeuristicBaseline,
    NearestLabelledPoint,
    PinholeView,
    dataset_depth,
    nearest_view_copy,
)
from ssnerf_method.evaluation.scoring import Predictor, predictor_statistics, score_predictor
from ssnerf_method.experiments.benchmark import (
    BenchmarkConfig,
    ModelRun,
    SceneBenchmark,
    generated_scenes,
    rendered_depth,
)
from ssnerf_method.experiments.launcher import Job, launch
from ssnerf_method.experiments.report import average, markdown
from ssnerf_method.experiments.studies import Results, StudyConfig, single, write_study_report
from ssnerf_method.experiments.transfer import PATH_KEYS, evenly_spaced
from ssnerf_method.label_makers.encoding import SEMANTIC_IGNORE
from ssnerf_method.label_makers.segments import SEGMENT_SCALE, grow_in_segments
from ssnerf_method.label_tool.suggest import frame_views, suggest_frames, training_frames
from ssnerf_method.metrics import class_iou
from ssnerf_method.properties import REGISTRY, class_property
from ssnerf_method.rendering.depth import rendered_z_depth

FrameChoice = Literal["even", "suggested"]
SSNERF, SSNERF_TRAIN = "SS-NeRF", "SS-NeRF, unlabelled training views"
HEURISTIC, NEAREST = "Heuristic (labelled frames)", "Nearest labelled frame copied"
NEAREST_POINT = "Nearest labelled point in 3D"
METHODS = (SSNERF, SSNERF_TRAIN, HEURISTIC, NEAREST, NEAREST_POINT)
"""The study's columns: SS-NeRF on the test and the unlabelled training views, then the baselines (test views)."""
ON_TRAIN = "baselines on the unlabelled training views"
DEPTH = "depth"
"""Key of a view's rendered z-depth in `model_predictor`'s predictions."""
ALL_FRAMES = "all frames"
CEILING = "mIoU ceiling (test classes labelled)"
"""Column of the highest test mIoU the labels allow (`class_coverage`)."""
BOUND = "all frames' SS-NeRF, unlabelled classes at 0"
"""Column: the dense model's per-class test IoU (`CLASS_IOU`) over the classes a labelled pixel shows, others 0."""
CLASS_IOU = "class_iou"
"""Key of the dense model's test IoU per class id (as a string) in its scores."""
SEEN = "test pixels a labelled frame sees"
ON_SEEN, ON_UNSEEN = "SS-NeRF on seen test pixels", "SS-NeRF on unseen test pixels"
"""Columns of SS-NeRF's test mIoU on the pixels of `SEEN` and on the rest (frame settings only)."""
DRAWS = "draws"
"""Key of a setting's SS-NeRF test mIoU per click draw (seed, as a string) in its scores, when it has several."""
DRAW = "SS-NeRF, draw {}"
LOWEST, HIGHEST = "SS-NeRF, lowest draw", "SS-NeRF, highest draw"


@dataclass(frozen=True)
class Setting:
    """One amount of labelling: k dense frames, c pixels per class per frame (grown at scale `grow`), or all."""

    frames: Optional[int] = None
    pixels: Optional[int] = None
    grow: Optional[float] = None
    choice: FrameChoice = "even"
    """How the k frames are chosen: evenly spaced, or as `ssnerf-label --suggest-frames k` suggests them."""

    @property
    def family(self) -> str:
        if self.frames is not None:
            return "frames" if self.choice == "even" else "suggested frames"
        if self.pixels is not None:
            return "pixels" if self.grow is None else "grown"
        return "dense"

    @property
    def name(self) -> str:
        if self.frames is not None:
            chosen = " suggested" if self.choice == "suggested" else ""
            return f"{self.frames}{chosen} frame{'s' if self.frames > 1 else ''}"
        if self.pixels is not None:
            return f"{self.pixels} px/class/frame" + ("" if self.grow is None else ", grown")
        return ALL_FRAMES

    def folder(self, scene: Path, seed: int = 0) -> str:
        """The copy's folder and runs' name; a pixel setting's nonzero seed is in it, so draws never share them."""
        suffix = f"{self.frames}frames" if self.frames is not None else f"{self.pixels}pixels"
        suffix += "-suggested" if self.frames is not None and self.choice == "suggested" else ""
        drawn = f"-draw{seed}" if self.pixels is not None and seed != 0 else ""
        return f"{scene.name}-{suffix}" + ("" if self.grow is None else f"-grown{self.grow:g}") + drawn


def split_images(scene: Path) -> Tuple[List[Path], List[Path]]:
    """The scene's training and test images (absolute), as nerfstudio's parser splits them."""
    parser = SSNeRFDataParserConfig(data=scene).setup()
    return ([Path(name).resolve() for name in parser.get_dataparser_outputs("train").image_filenames],
            [Path(name).resolve() for name in parser.get_dataparser_outputs("test").image_filenames])


def sparse_pixels(label: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    """`label` keeping `count` random pixels of each class it has (all of a class with fewer), the rest unlabelled."""
    kept = np.full_like(label, SEMANTIC_IGNORE)
    flat, out = label.reshape(-1), kept.reshape(-1)
    for class_id in np.unique(flat):
        if class_id == SEMANTIC_IGNORE:
            continue
        pixels = np.flatnonzero(flat == class_id)
        chosen = rng.choice(pixels, size=min(count, len(pixels)), replace=False)
        out[chosen] = class_id
    return kept


def class_coverage(scene: Path) -> Dict[str, Any]:
    """Which test-view classes the training labels of `scene` show, and the mIoU ceiling (unshown classes score 0)."""
    key = class_property().file_key
    train, test = (set(paths) for paths in split_images(scene))
    shown: set = set()
    tested: set = set()
    for frame in json.loads((scene / "transforms.json").read_text())["frames"]:
        image = (scene / frame["file_path"]).resolve()
        if key not in frame or image not in train | test:
            continue
        classes = {int(value) for value in np.unique(np.asarray(Image.open(scene / frame[key])))} - {SEMANTIC_IGNORE}
        (tested if image in test else shown).update(classes)
    return {"test_classes": len(tested), "test_classes_labelled": len(tested & shown),
            "labelled_test_class_ids": sorted(tested & shown),
            "miou_ceiling": len(tested & shown) / len(tested) if tested else None}


def class_ious(predict: Predictor, dataset: SSNeRFDataset, num_classes: int) -> Dict[str, float]:
    """`predict`'s IoU per class id (as a string; the classes of `dataset`'s labels) over its views."""
    spec = class_property()
    iou = class_iou(predictor_statistics(predict, dataset, [spec], num_classes)[spec.name]["confusion"])
    return {str(index): float(value) for index, value in enumerate(iou) if not value.isnan()}


def dense_bound(run: Dict[str, Any], dense: Dict[str, Any]) -> Optional[float]:
    """`BOUND` for one scene's run, from the dense run's `CLASS_IOU` of that scene; None without them."""
    ious, shown = dense.get(CLASS_IOU), run.get("labelled_test_class_ids")
    if not ious or shown is None:
        return None
    return sum(ious.get(str(index), 0.0) for index in shown) / len(ious)


def seen_pixels(
    train: SSNeRFDataset, test: SSNeRFDataset, frames: List[int]
) -> Optional[Dict[int, Tuple[Tensor, Tensor]]]:
    """Per test view, (H, W) masks of the pixels whose surface one of `frames` sees and of those (with a depth) none
    sees; None without depth maps. A frame's labels reach what it sees; the rest must be guessed."""
    if train.depth_files is None or test.depth_files is None or not frames:
        return None
    scale = train.metadata["dataparser_scale"]
    train_depth, test_depth = dataset_depth(train, scale), dataset_depth(test, scale)
    sources = [(PinholeView.from_cameras(train.cameras, index), train_depth(index)) for index in frames]
    masks = {}
    for index in range(len(test)):
        depth = test_depth(index)
        points, pixels = PinholeView.from_cameras(test.cameras, index).unproject(depth)
        hit = np.zeros(len(points), dtype=bool)
        for view, source_depth in sources:
            hit |= view.sees(points, source_depth)
        seen, unseen = np.zeros(depth.size, dtype=bool), np.zeros(depth.size, dtype=bool)
        seen[pixels[hit]], unseen[pixels[~hit]] = True, True
        masks[index] = (torch.from_numpy(seen.reshape(depth.shape)), torch.from_numpy(unseen.reshape(depth.shape)))
    return masks


def seen_share(masks: Optional[Dict[int, Tuple[Tensor, Tensor]]]) -> Optional[float]:
    """The share of the test views' pixels with a depth that the labelled frames see (`seen_pixels`)."""
    if not masks:
        return None
    seen = sum(int(pair[0].sum()) for pair in masks.values())
    total = seen + sum(int(pair[1].sum()) for pair in masks.values())
    return seen / total if total else None


def suggested_frames(scene: Path, count: int) -> List[str]:
    """The `count` training frames `ssnerf-label --suggest-frames` suggests for `scene` (from its depth), absolute."""
    transforms = load_transforms(scene)
    views = frame_views(transforms, training_frames(transforms), None)
    return [str((transforms.folder / pick.file_path).resolve()) for pick in suggest_frames(views, count).picks]


def make_propagation_dataset(scene: Path, destination: Path, setting: Setting, seed: int = 0) -> Dict[str, Any]:
    """Write the scene with its training semantics cut down to `setting`; returns what was kept and labelled."""
    key = class_property().file_key
    train = {str(path) for path in split_images(scene)[0]}
    root = scene.resolve()
    meta = json.loads((scene / "transforms.json").read_text())
    keys = {*PATH_KEYS, *(spec.file_key for spec in REGISTRY.values() if spec.file_key is not None)}
    ordered = [image for image in (str((root / frame["file_path"]).resolve()) for frame in meta["frames"])
               if image in train]
    chosen = set(train) if setting.frames is None else set(
        evenly_spaced(ordered, setting.frames) if setting.choice == "even" else suggested_frames(scene, setting.frames))
    for split in ("train_filenames", "val_filenames", "test_filenames"):
        if split in meta:
            meta[split] = [str(root / name) for name in meta[split]]
    rng = np.random.default_rng(seed)
    labelled = total = 0
    with StagedOutputFolder(destination, overwrite=True) as folder:
        for frame in meta["frames"]:
            frame.update({name: str(root / frame[name]) for name in keys if name in frame})
            image = str(Path(frame["file_path"]).resolve())  # (absolute now)
            if image not in train or key not in frame:
                continue
            label = np.asarray(Image.open(frame[key]))
            total += label.size
            if image not in chosen:
                del frame[key]
                continue
            if setting.pixels is not None:
                label = sparse_pixels(label, setting.pixels, rng)
                labelled += int((label != SEMANTIC_IGNORE).sum())
                if setting.grow is not None:
                    image = np.asarray(Image.open(frame["file_path"]).convert("RGB"))
                    label = grow_in_segments(label, image, setting.grow)
                relative = Path("semantics") / Path(frame["file_path"]).name
                (folder / relative).parent.mkdir(parents=True, exist_ok=True)
                Image.fromarray(label).save(folder / relative.with_suffix(".png"))
                frame[key] = str((destination / relative.with_suffix(".png")).resolve())
            else:
                labelled += int((label != SEMANTIC_IGNORE).sum())
        kept = sorted(image for image in chosen)
        meta["ssnerf_propagation"] = {"scene": str(root), "setting": setting.name, "labelled_frames": kept,
                                      "labelled_pixel_fraction": labelled / max(total, 1)}
        (folder / "transforms.json").write_text(json.dumps(meta, indent=2) + "\n")  # (the folder is staged)
    return meta["ssnerf_propagation"]


@dataclass
class PropagationStudy(StudyConfig):
    """Semantics from k labelled frames or c pixels per class per frame, against every frame's labels."""

    frames: Tuple[int, ...] = (1, 2, 4, 8)
    """Numbers k of densely labelled training frames; the every-frame model is always added."""
    frame_choice: Tuple[FrameChoice, ...] = ("even",)
    """How the k frames are chosen, a row per choice: `even` (evenly spaced along the capture) and/or `suggested`
    (as `ssnerf-label --suggest-frames k` suggests them: most of the scene seen, from the capture's depth)."""
    pixels: Tuple[int, ...] = (1, 5, 25)
    """Numbers c of labelled pixels per class per training frame."""
    grow_scale: float = SEGMENT_SCALE
    """Segmentation scale to grow each c's clicks over image segments (as `ssnerf-label --semantics-grow`); 0: none."""
    seeds: Tuple[int, ...] = (0,)
    """Seeds of the pixel settings' click draws; with several, each pixel setting is trained per draw and its row
    gives the mean, beside the lowest and highest draw (one click is noisy). Frame settings are trained once."""
    train_views_scored: int = 12
    """Unlabelled training views scored per model (evenly spaced among them)."""

    name = "propagation"
    scope = ("Each row trains the semantics SS-NeRF (RGB + semantics) on the scene with less of its training frames' "
             "semantic labels; mIoU on the test views as `ns-eval` computes it, and on training views without labels.")

    def settings(self) -> List[Setting]:
        frames, pixels = ((1, 2), (1,)) if self.quick and (self.frames, self.pixels) == (
            PropagationStudy.frames, PropagationStudy.pixels) else (self.frames, self.pixels)
        grown = [Setting(pixels=c, grow=self.grow_scale) for c in pixels] if self.grow_scale > 0 else []
        chosen = [Setting(frames=k, choice=choice) for choice in self.frame_choice for k in frames]
        return [*chosen, Setting(), *(Setting(pixels=c) for c in pixels), *grown]

    def draws(self, setting: Setting) -> Tuple[int, ...]:
        """The seeds `setting` is trained with: every seed for a pixel setting, the first for the rest."""
        if not self.seeds:
            raise ValueError("--seeds: give at least one seed (e.g. --seeds 0 1 2).")
        return self.seeds if setting.pixels is not None else self.seeds[:1]

    def benchmarks(self, config: BenchmarkConfig) -> Dict[Tuple[str, Setting, int], SceneBenchmark]:
        """Per (scene, setting, draw): the benchmark of its labelled copy (the scene itself for every frame)."""
        config = BenchmarkConfig(**{**vars(config), "properties": (class_property().name,),
                                    "all_properties_model": False})
        scenes = list(config.scenes) or generated_scenes(config)
        benches = {}
        for scene in scenes:
            for setting in self.settings():
                for seed in self.draws(setting):
                    if setting == Setting():
                        benches[(scene.name, setting, seed)] = SceneBenchmark(config, scene, scene.name)
                        continue
                    root = config.output / "propagation" / setting.folder(scene, seed)
                    if not (root / "transforms.json").is_file():
                        make_propagation_dataset(scene, root, setting, seed)
                    benches[(scene.name, setting, seed)] = SceneBenchmark(config, root, root.name)
        return benches

    @staticmethod
    def run_of() -> ModelRun:
        name = class_property().name
        return ModelRun(single(name), (name,))

    def jobs(self, config: BenchmarkConfig, scenes: List[Path]) -> List[Job]:
        return [bench.job(self.run_of()) for bench in self.benchmarks(config).values()]

    def run(self) -> Results:
        start = time.time()
        config = self.benchmark_config()
        config.output.mkdir(parents=True, exist_ok=True)
        benches = self.benchmarks(config)
        launch(config, [bench.job(self.run_of()) for bench in benches.values()])
        drawn: Dict[Tuple[str, Setting], Dict[int, Dict[str, Any]]] = {}
        for (scene, setting, seed), bench in benches.items():
            CONSOLE.print(f"[bold]propagation study, {scene}: {setting.name}"
                          + (f" (draw {seed})" if len(self.draws(setting)) > 1 else ""))
            drawn.setdefault((scene, setting), {})[seed] = self.score(bench, setting)
        results: Results = {}
        details: Dict[str, Any] = {}
        for (scene, setting), scores in drawn.items():
            results.setdefault(scene, {})[setting.name] = over_draws(scores)
            for seed, score in scores.items():  # a run record per trained model, each draw's its own
                run = setting.name if len(scores) == 1 else f"{setting.name}, draw {seed}"
                details.setdefault(scene, {})[run] = {
                    key: score.get(key) for key in ("train_seconds", "seed", "config", "dataset")}
        self.figure(results, config.output / "figure_propagation.png")
        write_study_report(self, results, details, time.time() - start)
        return results

    def score(self, bench: SceneBenchmark, setting: Setting) -> Dict[str, Any]:
        """A setting's model and the baselines scored, cached in its runs folder (missing scores added to a cache)."""
        run = self.run_of()
        metrics = bench.train_and_score(run)
        if "failed" in metrics:
            return metrics
        cache = bench.folder / f"propagation-{bench.config.method}-{bench.tag}.json"
        spec = class_property()
        key = spec.metric_prefix + "miou"
        cached = json.loads(cache.read_text()) if cache.is_file() else None
        dense = setting == Setting()
        wanted = {NEAREST_POINT, *([] if setting.pixels is not None else [ON_SEEN]), *([CLASS_IOU] if dense else [])}
        if cached is not None and wanted <= cached.keys():
            return {**cached, **class_coverage(bench.scene), **self._record(metrics, bench)}
        pipeline = bench.load(run.name)
        train: SSNeRFDataset = pipeline.datamanager.train_dataset  # type: ignore[assignment]
        num_classes = len(train.metadata.get("semantic_classes", []))
        labelled = [index for index in range(len(train)) if train.metadata["property_files"][spec.name][index]]
        test = bench.test_dataset(pipeline)
        truth = self.true_labels(bench, train)
        unlabelled = [index for index in range(len(train)) if setting.pixels is not None or index not in labelled]
        scored = [unlabelled[int(i)] for i in np.unique(np.linspace(0, len(unlabelled) - 1,
                                                                     min(self.train_views_scored, len(unlabelled)))
                                                         .round())] if unlabelled else []
        seen = None if setting.pixels is not None else seen_pixels(train, test, labelled)
        predict = model_predictor(pipeline)
        on_test, on_train = once_per_view(predict), once_per_view(predict)
        source_depth = (dataset_depth(train, train.metadata["dataparser_scale"]) if train.depth_files is not None
                        else rendered_depth(pipeline, train.cameras))
        nearest_point = NearestLabelledPoint(train, spec, num_classes, source_depth, labelled)
        points = {views: nearest_point.predictor(lambda cameras, index, memo=memo: memo(cameras, index)[DEPTH])
                  for views, memo in (("test", on_test), ("train", on_train))}
        added: Dict[str, Any] = {ON_SEEN: None, ON_UNSEEN: None}
        if seen is not None:
            for column, side in ((ON_SEEN, 0), (ON_UNSEEN, 1)):
                added[column] = score_predictor(on_test, test, [spec], num_classes,
                                                pixels={index: pair[side] for index, pair in seen.items()}).get(key)
        if dense:
            added[CLASS_IOU] = class_ious(on_test, test, num_classes)
        added[NEAREST_POINT] = score_predictor(points["test"], test, [spec], num_classes).get(key)
        point_on_train = score_predictor(points["train"], truth, [spec], num_classes,
                                         views=scored).get(key) if scored else None
        if cached is not None:
            cached.update(added)
            if scored:
                cached.setdefault(ON_TRAIN, {})[NEAREST_POINT] = point_on_train
            write_text_atomic(cache, json.dumps(cached, indent=2))
            return {**cached, **class_coverage(bench.scene), **self._record(metrics, bench)}
        scores: Dict[str, Any] = {SSNERF: metrics.get(key)}
        scores[SSNERF_TRAIN] = score_predictor(on_train, truth, [spec], num_classes,
                                               views=scored).get(key) if scored else None
        heuristic = HeuristicBaseline(train, [spec], num_classes, train.metadata["dataparser_scale"],
                                      bench.config.heuristic, source_depth, sources=labelled)
        nearest = nearest_view_copy(train, [spec], num_classes, bench.config.heuristic.angle_weight, sources=labelled)
        scores[HEURISTIC] = score_predictor(heuristic.predict_view, test, [spec], num_classes).get(key)
        scores[NEAREST] = score_predictor(nearest, test, [spec], num_classes).get(key)
        scores[ON_TRAIN] = {
            HEURISTIC: score_predictor(heuristic.predict_view, truth, [spec], num_classes, views=scored).get(key),
            NEAREST: score_predictor(nearest, truth, [spec], num_classes, views=scored).get(key),
            NEAREST_POINT: point_on_train,
        } if scored else {}
        propagation = json.loads((bench.scene / "transforms.json").read_text()).get("ssnerf_propagation", {})
        scores.update(labelled_frames=len(labelled), training_frames=len(train), train_views_scored=len(scored),
                      labelled_pixel_fraction=propagation.get("labelled_pixel_fraction", 1.0),
                      seen_by_labelled_frames=seen_share(seen), **added)
        write_text_atomic(cache, json.dumps(scores, indent=2))
        return {**scores, **class_coverage(bench.scene), **self._record(metrics, bench)}

    @staticmethod
    def _record(metrics: Dict[str, Any], bench: SceneBenchmark) -> Dict[str, Any]:
        return {"train_seconds": metrics.get("train_seconds"), "seed": metrics.get("seed"),
                "config": metrics.get("config"), "dataset": str(bench.scene)}

    @staticmethod
    def true_labels(bench: SceneBenchmark, train: SSNeRFDataset) -> SSNeRFDataset:
        """The training views with every label of the full scene (the copy's own lack them), in the copy's order."""
        source = json.loads((bench.scene / "transforms.json").read_text()).get("ssnerf_propagation", {}).get("scene")
        if source is None:
            return train
        parser = SSNeRFDataParserConfig(data=Path(source)).setup()
        full = SSNeRFDataset(parser.get_dataparser_outputs("train"))
        if [Path(name).name for name in full.image_filenames] != [Path(name).name for name in train.image_filenames]:
            raise RuntimeError(f"{bench.scene}: its training views are not the scene's ({source}); remove the copy")
        full.cameras = train.cameras  # the copy's world frame (the same poses, oriented and scaled alike)
        return full

    def tables(self, results: Results) -> Tuple[str, Dict[str, Any]]:
        """Rows: the settings; columns: each method's mIoU over the scenes and the measures the notes explain."""
        rows = []
        for setting in self.settings():
            runs = [scenes.get(setting.name, {}) for scenes in results.values()]
            row: Dict[str, Any] = {"row": setting.name}
            for method in METHODS:
                row[method] = average([run.get(method) for run in runs])
            dense = average([scenes.get(ALL_FRAMES, {}).get(SSNERF) for scenes in results.values()])
            row["SS-NeRF / all frames"] = None if row[SSNERF] is None or not dense else row[SSNERF] / dense
            row[CEILING] = average([run.get("miou_ceiling") for run in runs])
            row[BOUND] = average([dense_bound(scenes.get(setting.name, {}), scenes.get(ALL_FRAMES, {}))
                                  for scenes in results.values()])
            row[SEEN] = average([run.get("seen_by_labelled_frames") for run in runs])
            row[ON_SEEN] = average([run.get(ON_SEEN) for run in runs])
            row[ON_UNSEEN] = average([run.get(ON_UNSEEN) for run in runs])
            row["labelled pixels"] = average([run.get("labelled_pixel_fraction") for run in runs])
            # each draw's study average, its lowest and highest; a single draw has no `DRAWS`, so none
            by_draw = [average([run.get(DRAWS, {}).get(str(seed)) for run in runs]) for seed in self.draws(setting)]
            by_draw = [value for value in by_draw if value is not None]
            row[LOWEST], row[HIGHEST] = (min(by_draw), max(by_draw)) if by_draw else (None, None)
            rows.append(row)
        shared = [*METHODS, "SS-NeRF / all frames", CEILING, BOUND, SEEN, ON_SEEN, ON_UNSEEN]
        shared += [LOWEST, HIGHEST] if len(self.seeds) > 1 else []
        titles, columns = [*shared, "labelled pixels (fraction)"], [*shared, "labelled pixels"]
        per_scene = {scene: {name: {**{column: runs[name].get(column) for column in (*METHODS, ON_SEEN, ON_UNSEEN)},
                                    BOUND: dense_bound(runs[name], runs.get(ALL_FRAMES, {})),
                                    **{DRAW.format(seed): value for seed, value in runs[name].get(DRAWS, {}).items()}}
                             for name in runs} for scene, runs in results.items()}
        draws_text = (f" {LOWEST} and {HIGHEST}: with several click draws (`--seeds`), a pixel row's SS-NeRF is the "
                      "mean over the draws; these are the lowest and the highest of the draws' own averages over the "
                      "scenes (a draw: one seed's clicks on every scene); each scene's draws are in its own table."
                      if len(self.seeds) > 1 else "")
        text = ("mIoU ↑ (test views unless named), average over the scenes\n\n" + markdown(rows, columns, titles, 4)
                + f"\n\n{CEILING}: the share of the test views' classes that some labelled pixel shows, the highest "
                "mIoU any method can reach from these labels (a class no label shows scores 0). "
                f"{BOUND}: the mIoU these labels give if SS-NeRF carries them to the test views as well as every "
                "frame's labels train it (the all-frames model's per-class test IoU, with the classes no label shows "
                "scored 0); a row below it falls short in propagation, and its distance to the all-frames row is "
                "what the missing classes cost. "
                f"{SEEN}: the share of test pixels whose surface some labelled frame sees (with the scene's depth "
                f"maps; frame settings only); {ON_SEEN} and {ON_UNSEEN}: SS-NeRF's mIoU on those test pixels and on "
                "the rest (with a depth) apart, each over the classes it shows. Labelled pixels: those labelled "
                "by hand (a grown row counts its clicks, not the pixels they grew to)." + draws_text + "\n\n"
                "Figure: `figure_propagation.png`.")
        return text, {"propagation": rows, "per_scene": per_scene}

    def figure(self, results: Results, path: Path) -> Path:
        """mIoU against the fraction of pixels labelled (log): a curve per method and family, the dense model a line."""
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        _, data = self.tables(results)
        rows = {row["row"]: row for row in data["propagation"]}
        figure, axis = plt.subplots(figsize=(6.4, 5.0))
        styles = {SSNERF: "o-", SSNERF_TRAIN: "o:", HEURISTIC: "s--", NEAREST: "^-.", NEAREST_POINT: "d:"}
        families = {"frames": ("full", "k labelled frames"), "suggested frames": ("right", "k suggested frames"),
                    "pixels": ("none", "c pixels per class"),
                    "grown": ("left", "c pixels per class, grown")}
        for family, (marker_fill, description) in families.items():
            chosen = [setting for setting in self.settings() if setting.family == family]
            for colour, (method, style) in enumerate(styles.items()):  # a colour per method, a fill per family
                points = [(rows[s.name]["labelled pixels"], rows[s.name][method]) for s in chosen
                          if rows[s.name]["labelled pixels"] and rows[s.name][method] is not None]
                if points:
                    label = f"{method}, {description}"
                    axis.plot(*zip(*sorted(points)), style, color=f"C{colour}", fillstyle=marker_fill, label=label)
        dense = rows.get(ALL_FRAMES, {}).get(SSNERF)
        if dense is not None:
            axis.axhline(dense, color="grey", linewidth=0.8, label="SS-NeRF, every frame labelled")
        axis.set_xscale("log")
        axis.set_xlabel("fraction of training pixels labelled")
        axis.set_ylabel("semantics mIoU")
        axis.set_ylim(0.0, 1.0)  # the dense line stays inside the frame
        # below the axes, so that it covers no curve
        axis.legend(fontsize=6, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=2, frameon=False)
        figure.tight_layout()
        figure.savefig(path, dpi=150)
        plt.close(figure)
        return path


def over_draws(scores: Dict[int, Dict[str, Any]]) -> Dict[str, Any]:
    """One setting's scores on a scene from its draws: varying scores averaged, each draw's under `DRAWS`."""
    if len(scores) == 1:
        return next(iter(scores.values()))
    failed = [score for score in scores.values() if "failed" in score]
    if failed:
        return failed[0]
    runs = list(scores.values())
    merged = dict(runs[0])
    for key in (*METHODS, "labelled_pixel_fraction"):
        merged[key] = average([run.get(key) for run in runs])
    merged[ON_TRAIN] = {method: average([run.get(ON_TRAIN, {}).get(method) for run in runs])
                        for method in runs[0].get(ON_TRAIN, {})}
    merged[DRAWS] = {str(seed): score.get(SSNERF) for seed, score in scores.items()}
    return merged


def model_predictor(pipeline: Pipeline) -> Predictor:
    """A trained pipeline as a class predictor, with its rendered z-depth (world units, (H, W)) as `DEPTH`."""
    spec = class_property()

    def predict(cameras, index: int) -> Dict[str, torch.Tensor]:
        with torch.no_grad():
            outputs = pipeline.model.render_camera(cameras[index : index + 1])  # type: ignore[attr-defined]
        return {spec.name: outputs[spec.prediction_key].cpu(),
                DEPTH: rendered_z_depth(outputs)[..., 0].cpu().numpy().astype(np.float64)}

    return predict


def once_per_view(predict: Predictor) -> Predictor:
    """`predict` asked once per view index, so every score of one dataset's views shares its renders."""
    views: Dict[int, Dict[str, Any]] = {}

    def predict_once(cameras, index: int) -> Dict[str, Any]:
        if index not in views:
            views[index] = predict(cameras, index)
        return views[index]

    return predict_once
