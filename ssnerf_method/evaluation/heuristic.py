"""The paper's Heuristic baseline: a test view's labels forward-projected from the nearest training views.

The nearest views (`pose_distance`), lifted to 3D with a `DepthSource`, are z-buffer splatted into the test camera in
turn; holes take the nearest filled pixel. Normals are rotated (`PropertyKind.reframe`); class ids never blended.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Dict, List, Optional, Sequence, Tuple

import numpy as np
import torch
from jaxtyping import Float
from scipy.ndimage import distance_transform_edt
from scipy.spatial import cKDTree
from torch import Tensor

from nerfstudio.cameras.cameras import Cameras

from ssnerf_method.data.dataset import DEPTH_KEY, SSNeRFDataset
from ssnerf_method.data.pinhole import PinholeView
from ssnerf_method.data.spacing import ANGLE_WEIGHT
from ssnerf_method.label_makers.encoding import SEMANTIC_IGNORE
from ssnerf_method.properties import PropertySpec


def pose_distance(a: PinholeView, b: PinholeView, angle_weight: float = ANGLE_WEIGHT) -> float:
    """Distance between camera centres (scene units) plus `angle_weight` x the angle between viewing directions
    (radians): the nearest view is close and looks the same way."""
    cosine = float(np.clip(np.dot(-a.rotation[:, 2], -b.rotation[:, 2]), -1.0, 1.0))
    return float(np.linalg.norm(a.centre - b.centre)) + angle_weight * float(np.arccos(cosine))


def nearest_view_copy(
    train: SSNeRFDataset, specs: Sequence[PropertySpec], num_classes: int, angle_weight: float = ANGLE_WEIGHT,
    sources: Optional[Sequence[int]] = None,
) -> Callable[[Cameras, int], Dict[str, Tensor]]:
    """A predictor copying the nearest training view's labels (of `sources`, default all) unwarped: the floor."""
    views = {index: PinholeView.from_cameras(train.cameras, index)
             for index in (range(len(train)) if sources is None else sources)}

    def predict(cameras: Cameras, index: int) -> Dict[str, Tensor]:
        target = PinholeView.from_cameras(cameras, index)
        nearest = min(views, key=lambda source: pose_distance(target, views[source], angle_weight))
        item = train[nearest]
        return {spec.name: spec.kind.label_as_prediction(spec.label(item, num_classes), num_classes) for spec in specs}

    return predict


def splat(
    source: PinholeView, depth: Float[np.ndarray, "h w"], target: PinholeView
) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Z-buffered splat: for each target pixel hit, its flat index, the winning (nearest) source pixel's flat index
    and that point's z-depth in the target camera."""
    points, pixels = source.unproject(depth)
    column, row, z_target, inside = target.project(points)
    target_index = (row[inside] * target.width + column[inside]).astype(np.int64)
    source_index = pixels[inside]
    z_kept = z_target[inside]
    order = np.lexsort((z_kept, target_index))  # by target pixel, nearest first
    target_index, source_index, z_kept = target_index[order], source_index[order], z_kept[order]
    first = np.unique(target_index, return_index=True)[1]
    return target_index[first], source_index[first], z_kept[first]


def nearest_filled(filled: np.ndarray) -> np.ndarray:
    """(H, W) flat index of the nearest filled pixel of every pixel (itself where filled)."""
    _, (rows, cols) = distance_transform_edt(~filled, return_indices=True)
    return rows * filled.shape[1] + cols


DepthSource = Callable[[int], Float[np.ndarray, "h w"]]
"""Training-view index -> its z-depth map in world (dataparser) units; NaN or <= 0 where unknown."""


def dataset_depth(train: SSNeRFDataset, dataparser_scale: float) -> DepthSource:
    """The training views' own depth maps (metres on disk), in world units."""

    def depth(index: int) -> np.ndarray:
        item = train[index]
        if DEPTH_KEY not in item:
            raise ValueError(
                "the Heuristic baseline's dataset depth needs depth maps (frames' `depth_file_path` in "
                "transforms.json); without them, give it another depth source, e.g. a NeRF's rendered depth"
            )
        return item[DEPTH_KEY][..., 0].numpy().astype(np.float64) * dataparser_scale

    return depth


class NearestLabelledPoint:
    """Each pixel (lifted to 3D) takes the class of the nearest labelled 3D point of `sources`: the baseline for
    sparse labels (clicks, strokes), which the Heuristic's splat leaves nearly empty."""

    def __init__(self, train: SSNeRFDataset, spec: PropertySpec, num_classes: int, source_depth: DepthSource,
                 sources: Sequence[int]) -> None:
        self.spec, self.num_classes = spec, num_classes
        points, classes = [], []
        for index in sources:
            label = spec.label(train[index], num_classes)
            world, pixels = PinholeView.from_cameras(train.cameras, index).unproject(source_depth(index))
            labelled = spec.kind.valid(label).reshape(-1).numpy()[pixels]
            points.append(world[labelled])
            classes.append(label.reshape(-1, label.shape[-1])[torch.from_numpy(pixels[labelled])])
        self.tree = cKDTree(np.concatenate(points)) if sum(len(chunk) for chunk in points) else None
        self.known = torch.cat(classes) if self.tree is not None else None

    def predictor(
        self, target_depth: Callable[[Cameras, int], Float[np.ndarray, "h w"]]
    ) -> Callable[[Cameras, int], Dict[str, Tensor]]:
        """A `scoring.Predictor` lifting pixels with `target_depth`; depthless pixels take the nearest one's class."""
        spec, num_classes = self.spec, self.num_classes

        def predict(cameras: Cameras, index: int) -> Dict[str, Tensor]:
            target = PinholeView.from_cameras(cameras, index)
            if self.tree is None or self.known is None:
                label = spec.kind.missing(target.width, target.height, num_classes)
                return {spec.name: spec.kind.label_as_prediction(label, num_classes)}
            world, pixels = target.unproject(target_depth(cameras, index))
            flat = torch.full((target.height * target.width, self.known.shape[-1]), float(SEMANTIC_IGNORE))
            if len(pixels):
                flat[torch.from_numpy(pixels)] = self.known[torch.from_numpy(self.tree.query(world)[1])]
                filled = np.zeros(target.height * target.width, dtype=bool)
                filled[pixels] = True
                flat = flat[torch.from_numpy(nearest_filled(filled.reshape(target.height, target.width)).reshape(-1))]
            label = flat.reshape(target.height, target.width, -1)
            return {spec.name: spec.kind.label_as_prediction(label, num_classes)}

        return predict


@dataclass
class HeuristicBaselineConfig:
    """The Heuristic baseline's choices."""

    num_source_views: int = 2
    """Training views splatted in turn, nearest first (the rest of the holes take the nearest filled pixel)."""
    angle_weight: float = ANGLE_WEIGHT
    """Scene units of camera-centre distance one radian of viewing-direction difference counts for."""


class HeuristicBaseline:
    """Test views' labels forward-projected from the training views' with their `depth` (default: the dataset's)."""

    def __init__(
        self, train: SSNeRFDataset, specs: Sequence[PropertySpec], num_classes: int, dataparser_scale: float,
        config: Optional[HeuristicBaselineConfig] = None, depth: Optional[DepthSource] = None,
        sources: Optional[Sequence[int]] = None,
    ) -> None:
        self.train = train
        self.specs = [spec for spec in specs if spec.file_key is not None]
        self.num_classes = num_classes
        self.config = config or HeuristicBaselineConfig()
        self.depth_source = depth or dataset_depth(train, dataparser_scale)
        self.sources = list(range(len(train)) if sources is None else sources)
        """The training views it warps from (default: all; e.g. only the labelled ones)."""
        self.views = {index: PinholeView.from_cameras(train.cameras, index) for index in self.sources}
        self._items: Dict[int, Dict[str, Tensor]] = {}
        self._depths: Dict[int, np.ndarray] = {}

    def depth(self, index: int) -> np.ndarray:
        """A training view's z-depth in world units (asked of the depth source once)."""
        if index not in self._depths:
            self._depths[index] = self.depth_source(index)
        return self._depths[index]

    def item(self, index: int) -> Dict[str, Tensor]:
        if index not in self._items:
            self._items[index] = self.train[index]
        return self._items[index]

    def source_order(self, target: PinholeView) -> List[int]:
        distances = [pose_distance(target, self.views[index], self.config.angle_weight) for index in self.sources]
        return [self.sources[rank] for rank in np.argsort(distances, kind="stable")]

    def predict_view(self, cameras: Cameras, index: int) -> Dict[str, Tensor]:
        """Each property's prediction (in the model's prediction layout) for camera `index` of `cameras`."""
        labels = self.predict(PinholeView.from_cameras(cameras, index))
        return {spec.name: spec.kind.label_as_prediction(labels[spec.name], self.num_classes) for spec in self.specs}

    def predict(self, target: PinholeView) -> Dict[str, Tensor]:
        """Each property's warped label (label layout; unlabelled source pixels stay unlabelled) for `target`."""
        size = target.height * target.width
        winner_view = np.full(size, -1)
        winner_pixel = np.zeros(size, dtype=np.int64)
        for source_index in self.source_order(target)[: self.config.num_source_views]:
            hit, pixel, _ = splat(self.views[source_index], self.depth(int(source_index)), target)
            empty = winner_view[hit] < 0
            winner_view[hit[empty]], winner_pixel[hit[empty]] = source_index, pixel[empty]
        filled = (winner_view >= 0).reshape(target.height, target.width)
        if filled.any() and not filled.all():
            nearest = nearest_filled(filled).reshape(-1)
            winner_view, winner_pixel = winner_view[nearest], winner_pixel[nearest]
        return {spec.name: self._gather(spec, winner_view, winner_pixel, target) for spec in self.specs}

    def _gather(self, spec: PropertySpec, views: np.ndarray, pixels: np.ndarray, target: PinholeView) -> Tensor:
        channels = spec.kind.label_channels(self.num_classes)
        result = spec.kind.missing(target.width, target.height, self.num_classes).reshape(-1, channels)
        for source_index in np.unique(views[views >= 0]):
            chosen = views == source_index
            label = spec.label(self.item(int(source_index)), self.num_classes).reshape(-1, channels)
            rotation = torch.from_numpy(target.rotation.T @ self.views[int(source_index)].rotation).float()
            result[torch.from_numpy(chosen)] = spec.kind.reframe(label[torch.from_numpy(pixels[chosen])], rotation)
        return result.reshape(target.height, target.width, channels)
