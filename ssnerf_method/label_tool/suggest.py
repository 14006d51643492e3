"""Where labelling pays: the frames to annotate first (`ssnerf-label --suggest-frames K`) and the pixels to click
(`--suggest-clicks N`).

Frames: every training frame's depth (the capture's, or a trained model's rendered depth) lifted to surface points,
pooled into voxels of the scene; a frame covers the voxels it sees unhidden. Frames are picked greedily, each the one
that covers most of what the earlier picks (and the frames already annotated) leave, so K frames together see as much
of the scene as K frames can (greedy cover is within 1 - 1/e of the best). Labels reach what a labelled frame sees;
the rest is guessed.

Clicks: a trained model's class uncertainty (`class_uncertainty`) on every training frame, at a coarse resolution;
the most uncertain pixels are asked first, each at least a spacing in 3D from every question before it (the spacing
shrinks until N are found), so no two ask about the same surface; pixels already labelled are not asked.

Both work in the transforms file's frame: poses as written, depth in the file's units.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import TYPE_CHECKING, Callable, Dict, List, Optional, Sequence, Tuple

import numpy as np
from jaxtyping import Float

from ssnerf_method.data.io import DatasetInputError, write_json_atomic
from ssnerf_method.data.pinhole import PinholeView
from ssnerf_method.data.strokes import SUGGESTED_CLICKS_FILE
from ssnerf_method.data.transforms import Transforms, frame_camera, is_perspective
from ssnerf_method.label_makers.encoding import SEMANTIC_IGNORE
from ssnerf_method.label_tool.paths import LABEL_FOLDER

if TYPE_CHECKING:
    from ssnerf_method.label_tool.rendered_depth import DepthFromModel

SUGGESTED_FRAMES = "suggested_frames.json"
SUGGESTED_CLICKS = SUGGESTED_CLICKS_FILE.name
"""The files the suggestions go to, in the dataset's `ssnerf_labels/`."""
DEPTH_WIDTH = 96
"""Width (pixels) the depth and uncertainty are looked at: the scene's layout, not its detail, decides the picks."""
VOXELS_ACROSS = 96
"""The scene's surface is pooled into voxels of 1/`VOXELS_ACROSS` of its largest extent: the unit of its share."""
SEES_TOLERANCE = 0.03
"""A frame sees a surface point when its own depth there is within this fraction of the point's distance."""
CLICK_SPACING = 0.08
"""First spacing of suggested clicks in 3D, as a fraction of the scene's largest extent (halved until N fit)."""


@dataclass
class FrameView:
    """One training frame at the suggestion's resolution: its camera (file frame) and z-depth (file units)."""

    file_path: str
    view: PinholeView
    depth: Float[np.ndarray, "h w"]
    scale: float
    """The view's size over the image's (pixel (c, r) here covers image pixels from (c / scale, r / scale))."""


def training_frames(transforms: Transforms) -> List[Dict]:
    """The frames nerfstudio trains on (its parser's train split), in the file's order."""
    from ssnerf_method.data.dataparser import SSNeRFDataParserConfig
    from ssnerf_method.label_tool.rendered_depth import relative_image_path

    outputs = SSNeRFDataParserConfig(data=transforms.path).setup().get_dataparser_outputs("train")
    train = {relative_image_path(Path(name), transforms.folder) for name in outputs.image_filenames}
    return [frame for frame in transforms.frames
            if PurePosixPath(*[p for p in PurePosixPath(frame["file_path"]).parts if p != "."]) in train]


def frame_view(transforms: Transforms, frame: Dict, depth: Callable[[float], np.ndarray]) -> FrameView:
    """`frame` at `DEPTH_WIDTH` pixels wide with its depth from `depth(scale)` (resized to that size)."""
    import cv2

    camera = frame_camera(transforms, frame)
    if not is_perspective(camera):
        raise DatasetInputError(f"{transforms.path}: frame {frame['file_path']} is not a pinhole camera; suggestions "
                                "need perspective frames (undistorted pinhole or OPENCV).")
    scale = min(1.0, DEPTH_WIDTH / float(camera.width))
    camera.rescale_output_resolution(scale)
    view = PinholeView.from_cameras(camera, 0)
    view.camera_to_world = np.asarray(frame["transform_matrix"], dtype=np.float64)[:3]
    values = depth(scale)
    if values.shape != (view.height, view.width):
        values = cv2.resize(values.astype(np.float32), (view.width, view.height),
                            interpolation=cv2.INTER_NEAREST).astype(np.float64)
    return FrameView(frame["file_path"], view, values, scale)


def capture_depth(transforms: Transforms, frame: Dict) -> Callable[[float], np.ndarray]:
    """The frame's own depth map in the transforms file's units (`depth_unit_scale_factor`, nerfstudio's 1e-3 for
    millimetre PNGs), as nerfstudio reads it."""
    from nerfstudio.data.utils.data_utils import get_depth_image_from_path

    def read(scale: float) -> np.ndarray:
        camera = frame_camera(transforms, frame)
        width, height = int(camera.width), int(camera.height)
        unit = float(transforms.meta.get("depth_unit_scale_factor", 1e-3))
        depth = get_depth_image_from_path(transforms.file(frame["depth_file_path"]), height, width, unit)
        return depth[..., 0].numpy().astype(np.float64)

    return read


def frame_views(transforms: Transforms, frames: Sequence[Dict], model: Optional["DepthFromModel"],
                renders: Optional[Dict[str, Dict]] = None, on_frame: Callable[[], None] = lambda: None
                ) -> List[FrameView]:
    """`frames` with the capture's depth, or `model`'s rendered depth (required for frames without depth); with a
    model, `renders` receives each frame's outputs (by file_path)."""
    views = []
    for frame in frames:
        if model is not None:

            def rendered(scale: float, frame: Dict = frame) -> np.ndarray:
                outputs = model.render(transforms, frame, scale)
                if renders is not None:
                    renders[frame["file_path"]] = outputs
                return model.depth_of(outputs)

            views.append(frame_view(transforms, frame, rendered))
        elif "depth_file_path" in frame:
            views.append(frame_view(transforms, frame, capture_depth(transforms, frame)))
        else:
            raise DatasetInputError(
                f"{transforms.path}: frame {frame['file_path']} has no depth_file_path. Pass --load-config with the "
                f"config.yml of a model trained on this data (ssnerf-label's depth model is in "
                f"{LABEL_FOLDER}/depth_model/) to use its rendered depth.")
        on_frame()
    return views


@dataclass
class SurfaceVoxels:
    """The scene's surface as voxel centres (file frame), and which frames see each."""

    points: Float[np.ndarray, "n 3"]
    seen: np.ndarray
    """(frames, voxels) bool: frame f sees voxel v unhidden."""
    extent: float
    """The largest side of the surface's bounding box (file units)."""


def surface_voxels(views: Sequence[FrameView]) -> SurfaceVoxels:
    """Every frame's depth lifted to points, pooled into voxels, and each voxel's visibility from each frame."""
    points = np.concatenate([item.view.unproject(item.depth)[0] for item in views]) if views else np.zeros((0, 3))
    if not len(points):
        raise DatasetInputError("no frame has a depth value: nothing to cover. Check the depth maps (or the model).")
    low, high = points.min(axis=0), points.max(axis=0)
    extent = float((high - low).max()) or 1.0
    size = extent / VOXELS_ACROSS
    keys = np.floor((points - low) / size).astype(np.int64)
    _, inverse = np.unique(keys, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    centres = np.zeros((inverse.max() + 1, 3))
    np.add.at(centres, inverse, points)
    centres /= np.bincount(inverse)[:, None]
    seen = np.stack([item.view.sees(centres, item.depth, SEES_TOLERANCE) for item in views])
    return SurfaceVoxels(centres, seen, extent)


@dataclass
class FramePick:
    file_path: str
    added_share: float
    """Share of the scene's surface voxels this frame sees that no earlier pick (or annotated frame) sees."""


def greedy_cover(seen: np.ndarray, count: int, covered: Optional[np.ndarray] = None) -> List[Tuple[int, int]]:
    """(frame index, voxels added) of `count` frames, each the one adding most to what is `covered` (ties: the
    earlier frame); a frame is picked once."""
    covered = np.zeros(seen.shape[1], dtype=bool) if covered is None else covered.copy()
    picks: List[Tuple[int, int]] = []
    available = np.ones(len(seen), dtype=bool)
    for _ in range(min(count, len(seen))):
        gains = np.where(available, (seen & ~covered).sum(axis=1), -1)
        best = int(np.argmax(gains))
        picks.append((best, int(gains[best])))
        covered |= seen[best]
        available[best] = False
    return picks


@dataclass
class FrameSuggestion:
    picks: List[FramePick]
    annotated: List[str]
    """Training frames that already list semantics (their cover counted first, never suggested)."""
    annotated_share: float
    depth_source: str
    total_share: float = field(init=False)

    def __post_init__(self) -> None:
        self.total_share = self.annotated_share + sum(pick.added_share for pick in self.picks)

    def record(self) -> Dict:
        return {"frames": [pick.file_path for pick in self.picks],
                "added_share": [round(pick.added_share, 4) for pick in self.picks],
                "already_annotated": self.annotated, "already_annotated_share": round(self.annotated_share, 4),
                "depth": self.depth_source}


def suggest_frames(views: Sequence[FrameView], count: int, annotated: Sequence[str] = (),
                   depth_source: str = "capture depth") -> FrameSuggestion:
    """`count` frames of `views` to annotate, in order, for the most surface seen (see the module docstring)."""
    voxels = surface_voxels(views)
    total = voxels.seen.shape[1]
    done = [index for index, item in enumerate(views) if item.file_path in set(annotated)]
    covered = voxels.seen[done].any(axis=0) if done else np.zeros(total, dtype=bool)
    candidates = [index for index in range(len(views)) if index not in done]
    picks = greedy_cover(voxels.seen[candidates], count, covered)
    return FrameSuggestion([FramePick(views[candidates[index]].file_path, gain / total) for index, gain in picks],
                           [views[index].file_path for index in done], float(covered.mean()), depth_source)


@dataclass
class Click:
    """A pixel asked about: its frame, full-resolution column and row, the model's guess and its uncertainty."""

    file_path: str
    x: int
    y: int
    guess: str
    uncertainty: float
    point: Tuple[float, float, float]
    """The surface point asked about (transforms file's frame), where the viewer marks the question."""

    def record(self) -> Dict:
        return {"file_path": self.file_path, "x": self.x, "y": self.y, "class": None, "guess": self.guess,
                "uncertainty": round(self.uncertainty, 4), "point": [round(value, 6) for value in self.point]}


@dataclass
class ClickCandidates:
    """Every pixel that may be asked: its frame index, view pixel, 3D point, uncertainty and the guessed class id."""

    frame: np.ndarray
    pixel: np.ndarray
    points: Float[np.ndarray, "n 3"]
    uncertainty: np.ndarray
    guess: np.ndarray


def spread_picks(points: Float[np.ndarray, "n 3"], order: np.ndarray, count: int, spacing: float) -> List[int]:
    """Up to `count` indices taken along `order` (most wanted first), each at least `spacing` from every one taken
    before; the spacing halves and the walk repeats until `count` are taken or every candidate is."""
    taken: List[int] = []
    used = np.zeros(len(points), dtype=bool)
    while len(taken) < min(count, len(points)):
        for index in order:
            if len(taken) >= count:
                break
            if used[index]:
                continue
            if taken and np.min(np.linalg.norm(points[taken] - points[index], axis=1)) < spacing:
                continue
            taken.append(int(index))
            used[index] = True
        spacing /= 2.0
        if spacing < 1e-9:
            spacing = 0.0
    return taken


def suggest_clicks(views: Sequence[FrameView], uncertainty: Sequence[np.ndarray], guesses: Sequence[np.ndarray],
                   labelled: Sequence[Optional[np.ndarray]], class_names: Sequence[str], count: int,
                   image_sizes: Sequence[Tuple[int, int]]) -> List[Click]:
    """`count` pixels of `views` to ask about: most uncertain first, spread in 3D (see the module docstring).
    `labelled[i]`: frame i's (H, W) class ids at full size (or None), whose labelled pixels are not asked."""
    frames, pixels, points, values, ids = [], [], [], [], []
    for index, item in enumerate(views):
        world, flat = item.view.unproject(item.depth)
        rows, columns = np.divmod(flat, item.view.width)
        width, height = image_sizes[index]
        x = np.minimum(((columns + 0.5) / item.scale).astype(np.int64), width - 1)
        y = np.minimum(((rows + 0.5) / item.scale).astype(np.int64), height - 1)
        keep = np.ones(len(flat), dtype=bool)
        if labelled[index] is not None:
            keep = labelled[index][y, x] == SEMANTIC_IGNORE
        frames.append(np.full(int(keep.sum()), index))
        pixels.append(np.stack([x, y], axis=-1)[keep])
        points.append(world[keep])
        values.append(uncertainty[index].reshape(-1)[flat][keep])
        ids.append(guesses[index].reshape(-1)[flat][keep])
    candidates = ClickCandidates(*(np.concatenate(parts) for parts in (frames, pixels, points, values, ids)))
    if not len(candidates.frame):
        return []
    extent = float((candidates.points.max(axis=0) - candidates.points.min(axis=0)).max()) or 1.0
    order = np.argsort(-candidates.uncertainty, kind="stable")
    chosen = spread_picks(candidates.points, order, count, CLICK_SPACING * extent)
    return [Click(views[int(candidates.frame[i])].file_path, int(candidates.pixel[i, 0]), int(candidates.pixel[i, 1]),
                  class_names[int(candidates.guess[i])] if int(candidates.guess[i]) < len(class_names) else "?",
                  float(candidates.uncertainty[i]), tuple(float(v) for v in candidates.points[i]))  # type: ignore
            for i in chosen]


def suggestion_path(folder: Path, name: str) -> Path:
    return folder / LABEL_FOLDER / name


def write_frame_suggestion(folder: Path, suggestion: FrameSuggestion) -> Path:
    path = suggestion_path(folder, SUGGESTED_FRAMES)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(path, suggestion.record())
    return path


def write_click_suggestion(folder: Path, clicks: Sequence[Click], source: str) -> Path:
    path = suggestion_path(folder, SUGGESTED_CLICKS)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(path, {"clicks": [click.record() for click in clicks], "model": source,
                             "answer": "fill each \"class\" with a class name (null: skip), then "
                                       "ssnerf-label DATA --annotations " + str(path)})
    return path
