"""Dataparser for the SS-NeRF dataset format: nerfstudio's `transforms.json` plus per-frame property files.

nerfstudio's own parser reads cameras, images, depth and splits; this one adds, per output image, the path of each
property label (the registry's `file_key`), the class list and colours, and each camera's pose as ray metadata.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional, Type

from nerfstudio.data.dataparsers.base_dataparser import DataparserOutputs
from nerfstudio.data.dataparsers.nerfstudio_dataparser import Nerfstudio, NerfstudioDataParserConfig
from nerfstudio.plugins.registry_dataparser import DataParserSpecification
from nerfstudio.utils.io import load_from_json

from ssnerf_method.data.pose_metadata import add_pose_metadata
from ssnerf_method.data.strokes import STROKES_FILE, StrokeStore, merged_classes
from ssnerf_method.data.validate import transforms_file, validate_dataset
from ssnerf_method.properties import REGISTRY, class_property

STROKES_METADATA_KEY = "strokes"
"""Metadata key of the dataset's `StrokeStore` (present when the dataset trains classes)."""


@dataclass
class SSNeRFDataParserConfig(NerfstudioDataParserConfig):
    """nerfstudio's dataparser plus the SS-NeRF property files."""

    _target: Type = field(default_factory=lambda: SSNeRFDataParser)
    check_contents: bool = False
    """Also read every label's pixels before anything is built (class ids in range, unit normals, depth not all
    zero), as `ssnerf-check` does. Off (default), validation reads headers only and the pixels are checked once, as
    the dataset decodes them for training (before step 0): the full read doubles loading a large dataset."""


class SSNeRFDataParser(Nerfstudio):
    """Validates the dataset (`data/validate.py`), then reads the property keys of each frame."""

    config: SSNeRFDataParserConfig
    _validated: bool = False
    _strokes: Optional[StrokeStore] = None

    def _generate_dataparser_outputs(self, split: str = "train", **kwargs) -> DataparserOutputs:
        if not self._validated:  # once per parser: train and eval splits share the files
            validate_dataset(self.config.data, contents=self.config.check_contents).raise_if_faulty(self.config.data)
            self._validated = True
        data_dir = self.config.data if self.config.data.is_dir() else self.config.data.parent
        transforms_path = transforms_file(self.config.data)
        outputs = super()._generate_dataparser_outputs(split, **kwargs)
        meta = load_from_json(transforms_path)
        frames = {self._get_fname(Path(frame["file_path"]), data_dir): frame for frame in meta["frames"]}
        output_frames = [frames[path] for path in outputs.image_filenames]

        property_files: Dict[str, List[Optional[Path]]] = {}
        for spec in REGISTRY.values():
            if spec.file_key is None or not any(spec.file_key in frame for frame in meta["frames"]):
                continue
            property_files[spec.name] = [
                data_dir / frame[spec.file_key] if spec.file_key in frame else None for frame in output_frames
            ]
        declared = list(meta.get("semantic_classes") or [])
        classes, colors = declared, meta.get("semantic_colors")
        strokes = None
        labelled_classes = class_property()
        if declared or labelled_classes.name in property_files or (data_dir / STROKES_FILE).exists():
            # classes can be trained: from label files, or from strokes painted in the viewer (the dataset declares
            # its classes, e.g. `ssnerf-label DATA --semantic-classes ...`, and may have no label file at all)
            if self._strokes is None:
                self._strokes = StrokeStore.of_dataset(data_dir)
            strokes = self._strokes
            classes, _ = merged_classes(declared, strokes)
            property_files.setdefault(labelled_classes.name, [None] * len(output_frames))

        label_sizes = [
            (int(frame.get("w", meta.get("w", 0))), int(frame.get("h", meta.get("h", 0)))) for frame in output_frames
        ]
        outputs.metadata.update(
            {
                "property_files": property_files,
                "available_properties": tuple(property_files),
                "semantic_classes": classes,
                "semantic_colors": colors,
                "declared_classes": len(declared),
                STROKES_METADATA_KEY: strokes,
                "label_sizes": label_sizes,
                "dataparser_scale": float(outputs.dataparser_scale),
            }
        )
        add_pose_metadata(outputs.cameras)
        return outputs


ssnerf_dataparser = DataParserSpecification(
    config=SSNeRFDataParserConfig(),
    description="nerfstudio transforms.json with SS-NeRF property files (semantics, normals, shading, ...).",
)
