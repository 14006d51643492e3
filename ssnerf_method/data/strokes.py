"""Strokes painted in the viewer: labelled rays (origin, direction, class) kept in `DATA/ssnerf_labels/strokes.json`.

A stroke (a click's disc, a drag's box) is a ray per painted pixel and a class by name, so it survives a growing class
list. Rays are in transforms.json's world frame, which unlike nerfstudio's does not depend on dataparser settings
(`WorldFrame` converts). Each change rewrites the file atomically, so a crash loses no earlier stroke.
"""

from __future__ import annotations

import json
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, List, Optional, Sequence, Tuple

import numpy as np
import torch
from jaxtyping import Float
from torch import Tensor

from nerfstudio.cameras.cameras import Cameras

from ssnerf_method.atomic import atomic_file
from ssnerf_method.data.io import DatasetInputError

STROKES_FILE = Path("ssnerf_labels") / "strokes.json"
"""Where a dataset keeps its strokes, relative to the dataset folder (beside `ssnerf-label`'s label folders)."""
SUGGESTED_CLICKS_FILE = Path("ssnerf_labels") / "suggested_clicks.json"
"""Where `ssnerf-label --suggest-clicks` writes its questions, which the viewer's Label panel asks too."""
FORMAT = "ssnerf-strokes"
"""The file's `format` key (a JSON that lacks it is not a strokes file)."""


@dataclass
class Stroke:
    """The rays one click or drag painted, in the dataset's world frame, and the class they were painted with."""

    class_name: str
    origins: Float[np.ndarray, "rays 3"]
    directions: Float[np.ndarray, "rays 3"]
    """Unit directions."""
    camera_to_world: Float[np.ndarray, "3 4"]
    """The viewer camera it was painted from (the pose input of pose-conditioned decoders)."""
    pixel_area: float
    """Solid angle of one painted pixel (nerfstudio's `RayBundle.pixel_area`)."""

    def to_json(self) -> Dict[str, Any]:
        return {
            "class": self.class_name,
            "camera_to_world": np.round(self.camera_to_world, 7).tolist(),
            "pixel_area": self.pixel_area,
            "origins": np.round(self.origins, 7).tolist(),
            "directions": np.round(self.directions, 7).tolist(),
        }

    @classmethod
    def from_json(cls, item: Dict[str, Any]) -> "Stroke":
        origins = np.asarray(item["origins"], dtype=np.float64).reshape(-1, 3)
        directions = np.asarray(item["directions"], dtype=np.float64).reshape(-1, 3)
        if len(origins) != len(directions) or not len(origins):
            raise ValueError("origins and directions must list the same, non-zero number of rays")
        camera = np.asarray(item["camera_to_world"], dtype=np.float64)
        if camera.shape != (3, 4):
            raise ValueError(f"camera_to_world must be 3x4, got {camera.shape}")
        if not (np.isfinite(origins).all() and np.isfinite(directions).all() and np.isfinite(camera).all()):
            raise ValueError("a ray or the camera is not finite")
        return cls(str(item["class"]), origins, directions / np.linalg.norm(directions, axis=-1, keepdims=True),
                   camera, float(item["pixel_area"]))


@dataclass
class WorldFrame:
    """nerfstudio's world frame of a run: `p_run = scale * (R @ p + t)` for a point `p` of the dataset's frame
    (`DataparserOutputs.dataparser_transform` is [R | t], `dataparser_scale` the scale)."""

    transform: Float[np.ndarray, "3 4"] = field(default_factory=lambda: np.eye(4)[:3])
    scale: float = 1.0

    @classmethod
    def of(cls, dataparser_outputs) -> "WorldFrame":
        return cls(dataparser_outputs.dataparser_transform.detach().cpu().numpy().astype(np.float64),
                   float(dataparser_outputs.dataparser_scale))

    def to_run(self, points: np.ndarray) -> np.ndarray:
        return self.scale * (points @ self.transform[:, :3].T + self.transform[:, 3])

    def from_run(self, points: np.ndarray) -> np.ndarray:
        return (points / self.scale - self.transform[:, 3]) @ self.transform[:, :3]

    def rotate_to_run(self, vectors: np.ndarray) -> np.ndarray:
        return vectors @ self.transform[:, :3].T

    def rotate_from_run(self, vectors: np.ndarray) -> np.ndarray:
        return vectors @ self.transform[:, :3]

    def camera_to_run(self, camera_to_world: np.ndarray) -> np.ndarray:
        rotation = self.transform[:, :3] @ camera_to_world[:, :3]
        return np.concatenate([rotation, self.to_run(camera_to_world[:, 3])[:, None]], axis=1)

    def camera_from_run(self, camera_to_world: np.ndarray) -> np.ndarray:
        rotation = self.transform[:, :3].T @ camera_to_world[:, :3]
        return np.concatenate([rotation, self.from_run(camera_to_world[:, 3])[:, None]], axis=1)


@dataclass
class LabelledRays:
    """Every stroke's rays in a run's world frame, with their class ids: what the datamanager mixes into batches."""

    origins: Float[Tensor, "rays 3"]
    directions: Float[Tensor, "rays 3"]
    class_ids: Float[Tensor, "rays 1"]
    camera_to_world: Float[Tensor, "rays 12"]
    pixel_area: Float[Tensor, "rays 1"]
    directions_norm: Float[Tensor, "rays 1"]
    """Length of each direction before normalisation, camera z = -1 (nerfstudio's `directions_norm`: z-depth)."""

    def __len__(self) -> int:
        return len(self.origins)


class StrokeStore:
    """One dataset's strokes, written through to its file; thread-safe (the viewer adds while training reads)."""

    def __init__(self, path: Path, strokes: Sequence[Stroke] = (), classes: Sequence[str] = ()) -> None:
        self.path = path
        self._strokes: List[Stroke] = list(strokes)
        self._classes: List[str] = list(classes)
        self._lock = threading.Lock()
        self.version = 0
        """Increases with every change, so readers know when to rebuild what they made from the strokes."""

    def __deepcopy__(self, memo: Dict) -> "StrokeStore":
        """The same store: it stands for one file, and nerfstudio deep-copies the dataset metadata that holds it."""
        return self

    def __getstate__(self) -> Dict[str, Any]:
        return {key: value for key, value in self.__dict__.items() if key != "_lock"}

    def __setstate__(self, state: Dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._lock = threading.Lock()

    @classmethod
    def of_dataset(cls, data: Path) -> "StrokeStore":
        """The store of the dataset at `data` (a folder or its transforms .json), read when the file exists."""
        folder = data if data.is_dir() or data.suffix != ".json" else data.parent
        return cls.load(folder / STROKES_FILE)

    @classmethod
    def load(cls, path: Path) -> "StrokeStore":
        """Read a strokes file (empty store if none); a `DatasetInputError` naming the file if it does not parse."""
        if not path.exists():
            return cls(path)
        fix = "Fix the file or delete it (it holds only the strokes painted in the viewer; nothing else reads it)."
        try:
            data = json.loads(path.read_text())
            if not isinstance(data, dict) or data.get("format") != FORMAT:
                raise ValueError(f'not a strokes file (no "format": "{FORMAT}")')
            strokes = []
            for number, item in enumerate(data.get("strokes", [])):
                try:
                    strokes.append(Stroke.from_json(item))
                except (KeyError, TypeError, ValueError) as err:
                    raise ValueError(f"stroke {number}: {err}") from err
            classes = [str(name) for name in data.get("classes", [])]
        except (OSError, UnicodeDecodeError, ValueError, TypeError) as err:
            raise DatasetInputError(f"{path}: strokes cannot be read ({err}). {fix}") from err
        return cls(path, strokes, classes)

    @property
    def strokes(self) -> List[Stroke]:
        with self._lock:
            return list(self._strokes)

    @property
    def classes(self) -> List[str]:
        """Class names added in the viewer (after the dataset's own), in the order they were added."""
        with self._lock:
            return list(self._classes)

    def num_rays(self) -> int:
        with self._lock:
            return sum(len(stroke.origins) for stroke in self._strokes)

    def add(self, stroke: Stroke) -> None:
        """Append a stroke and write the file (atomically) before returning."""
        with self._lock:
            self._write([*self._strokes, stroke], self._classes)
            self._strokes.append(stroke)

    def add_class(self, name: str) -> None:
        """Record a class added in the viewer (written at once: the next run knows its name and id)."""
        with self._lock:
            if name not in self._classes:
                self._write(self._strokes, [*self._classes, name])
                self._classes.append(name)

    def undo(self) -> Optional[Stroke]:
        """Remove the last stroke (written at once); None when there is none."""
        with self._lock:
            if not self._strokes:
                return None
            self._write(self._strokes[:-1], self._classes)
            return self._strokes.pop()

    def _write(self, strokes: Sequence[Stroke], classes: Sequence[str]) -> None:
        """The whole file holding `strokes` and `classes`, atomically (call with the lock held; the store takes them
        only once they are written, so it never holds what the file lacks)."""
        data = {"format": FORMAT, "version": 1,
                "frame": "the world frame of transforms.json (before nerfstudio orients and scales the poses)",
                "classes": list(classes), "strokes": [stroke.to_json() for stroke in strokes]}
        with atomic_file(self.path) as stream:
            json.dump(data, stream)
            stream.write("\n")
        self.version += 1

    def labelled_rays(self, frame: WorldFrame, class_ids: Dict[str, int]) -> Optional[LabelledRays]:
        """Every stroke's rays in a run's world frame, strokes of classes without an id left out; None if none."""
        strokes = [stroke for stroke in self.strokes if stroke.class_name in class_ids]
        if not strokes:
            return None
        origins = np.concatenate([frame.to_run(stroke.origins) for stroke in strokes])
        directions = np.concatenate([frame.rotate_to_run(stroke.directions) for stroke in strokes])
        directions /= np.linalg.norm(directions, axis=-1, keepdims=True)
        cameras = [frame.camera_to_run(stroke.camera_to_world) for stroke in strokes]
        counts = [len(stroke.origins) for stroke in strokes]
        poses = np.concatenate([np.repeat(camera.reshape(1, 12), count, 0) for camera, count in zip(cameras, counts)])
        optical_axis = np.concatenate([np.repeat(-camera[None, :, 2], count, 0) for camera, count in
                                       zip(cameras, counts)])
        cosine = np.clip((directions * optical_axis).sum(-1, keepdims=True), 1e-6, None)

        def tensor(array: np.ndarray) -> Tensor:
            return torch.from_numpy(np.ascontiguousarray(array)).float()

        return LabelledRays(
            origins=tensor(origins), directions=tensor(directions),
            class_ids=tensor(np.concatenate([np.full((count, 1), class_ids[stroke.class_name])
                                             for stroke, count in zip(strokes, counts)])),
            camera_to_world=tensor(poses),
            pixel_area=tensor(np.concatenate([np.full((count, 1), stroke.pixel_area)
                                              for stroke, count in zip(strokes, counts)])),
            directions_norm=tensor(1.0 / cosine),
        )


def merged_classes(declared: Sequence[str], store: StrokeStore) -> Tuple[List[str], List[str]]:
    """The run's class names: the dataset's, then those added in the viewer that it lacks. Returns (all, added)."""
    added = [name for name in store.classes if name not in declared]
    return [*declared, *added], added


def stroke_from_pixels(
    camera: Cameras, pixels: np.ndarray, class_name: str, frame: WorldFrame
) -> Stroke:
    """The stroke of `pixels` (column, row) of `camera` (in the run's world frame), stored in the dataset's frame."""
    coords = torch.from_numpy(pixels[:, ::-1].astype(np.float32) + 0.5)  # nerfstudio's (row, column), pixel centres
    bundle = camera.generate_rays(camera_indices=0, coords=coords)
    camera_to_world = camera.camera_to_worlds.reshape(3, 4).double().numpy()
    return Stroke(
        class_name=class_name,
        origins=frame.from_run(bundle.origins.double().numpy()),
        directions=frame.rotate_from_run(bundle.directions.double().numpy()),
        camera_to_world=frame.camera_from_run(camera_to_world),
        pixel_area=float(bundle.pixel_area.mean()),
    )
