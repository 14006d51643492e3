"""Suggested clicks answered in the viewer's Label panel: the questions `ssnerf-label --suggest-clicks` wrote in
`DATA/ssnerf_labels/suggested_clicks.json`, one at a time.

An answer is saved as a stroke is (one ray through the click's pixel from its frame's camera, written atomically to the
strokes file, which the next `ns-train` reads) and then written into the suggestion file (its `"class"`), so the next
question is the next unanswered one and `ssnerf-label --annotations` would import the same answers. A skipped click is
marked `"skipped": true` and not asked again.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Dict, List, Optional

import numpy as np
import torch

from ssnerf_method.data.io import DatasetInputError, write_json_atomic
from ssnerf_method.data.strokes import SUGGESTED_CLICKS_FILE, Stroke, WorldFrame, stroke_from_pixels
from ssnerf_method.data.transforms import frame_camera, load_transforms


@dataclass
class Question:
    """One suggested click: its index in the file, frame, pixel, the model's guess and the surface point asked about."""

    index: int
    file_path: str
    x: int
    y: int
    guess: Optional[str]
    uncertainty: Optional[float]
    point: Optional[np.ndarray]


class Questions:
    """The suggestion file of a dataset, read afresh for each question (ssnerf-label may rewrite it meanwhile)."""

    def __init__(self, data: Path) -> None:
        self.data = data
        self.path = data / SUGGESTED_CLICKS_FILE

    def _read(self) -> Dict[str, Any]:
        try:
            content = json.loads(self.path.read_text())
        except FileNotFoundError:
            raise DatasetInputError(f"{self.path}: no suggested clicks yet. Write them with ssnerf-label "
                                    f"{self.data} --suggest-clicks 20 --load-config CONFIG.") from None
        except (OSError, ValueError) as err:
            raise DatasetInputError(f"{self.path}: cannot be read ({err}). Write it again with ssnerf-label "
                                    "--suggest-clicks.") from err
        if not isinstance(content, dict) or not isinstance(content.get("clicks"), list):
            raise DatasetInputError(f"{self.path}: holds no \"clicks\" list. Write it again with ssnerf-label "
                                    "--suggest-clicks.")
        return content

    def counts(self) -> Dict[str, int]:
        clicks = self._read()["clicks"]
        answered = sum(1 for click in clicks if isinstance(click, dict) and click.get("class") is not None)
        skipped = sum(1 for click in clicks if isinstance(click, dict) and click.get("skipped"))
        return {"total": len(clicks), "answered": answered, "skipped": skipped}

    def next(self) -> Optional[Question]:
        """The first click neither answered nor skipped, or None."""
        for index, click in enumerate(self._read()["clicks"]):
            if isinstance(click, dict) and click.get("class") is None and not click.get("skipped"):
                point = click.get("point")
                return Question(index, str(click.get("file_path")), int(click.get("x", -1)), int(click.get("y", -1)),
                                click.get("guess"), click.get("uncertainty"),
                                None if point is None else np.asarray(point, dtype=np.float64))
        return None

    def stroke(self, question: Question, class_name: str) -> Stroke:
        """The answer as a stroke: the ray through the click's pixel centre from its frame's camera (file frame)."""
        transforms = load_transforms(self.data)
        frame = next((frame for frame in transforms.frames if frame["file_path"] == question.file_path), None)
        if frame is None:
            raise DatasetInputError(f"{self.path}: click {question.index} is on {question.file_path}, which is not a "
                                    f"frame of {transforms.path}. Write the suggestions again.")
        camera = frame_camera(transforms, frame)
        if not (0 <= question.x < int(camera.width) and 0 <= question.y < int(camera.height)):
            raise DatasetInputError(f"{self.path}: click {question.index} at ({question.x}, {question.y}) is outside "
                                    f"{question.file_path}. Write the suggestions again.")
        camera.camera_to_worlds = torch.tensor(frame["transform_matrix"], dtype=torch.float32)[None, :3]
        return stroke_from_pixels(camera, np.array([[question.x, question.y]]), class_name, WorldFrame())

    def mark(self, question: Question, class_name: Optional[str]) -> None:
        """Write the answer (or, with None, the skip) into the suggestion file."""
        content = self._read()
        clicks: List[Any] = content["clicks"]
        if not (0 <= question.index < len(clicks)) or clicks[question.index].get("file_path") != question.file_path:
            raise DatasetInputError(f"{self.path}: changed while the question was open. Ask for the next click again.")
        if class_name is None:
            clicks[question.index]["skipped"] = True
        else:
            clicks[question.index]["class"] = class_name
        write_json_atomic(self.path, content)
