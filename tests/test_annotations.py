"""`ssnerf-label --annotations`: COCO (polygons, RLE both ways) and labelme files written here from known masks import
to exactly those class ids; overlaps, frames without annotations, class names (appended or fixed), colours,
provenance, a class list declared alone, and the bad-input table (one line naming the file, nothing written)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Callable, Dict, List, Optional

import numpy as np
import pytest
from PIL import Image
from pycocotools import mask as coco_mask

from ssnerf_method.cli.check import CheckConfig
from ssnerf_method.cli.check import main as check_main
from ssnerf_method.cli.label import main as label_main
from ssnerf_method.data.dataparser import SSNeRFDataParserConfig
from ssnerf_method.data.io import DatasetInputError
from ssnerf_method.data.transforms import load_transforms
from ssnerf_method.label_makers.makers import LabelOptions
from ssnerf_method.label_tool.label_dataset import LABELLED, LabelDatasetConfig, label_dataset
from ssnerf_method.properties import OPTIONAL_PROPERTIES, REGISTRY
from ssnerf_method.rendering.palette import default_palette

from conftest import CLASSES, HEIGHT, WIDTH, ssnerf_label_refuses, write_tiny_dataset

ONLY_SEMANTICS = dict(normals=False, shading=False, edges=False, keypoints=False)


@pytest.fixture
def data(tmp_path: Path) -> Path:
    """The tiny 16x12 dataset (6 frames, classes void/wall/floor/table) with no labels listed."""
    root = tmp_path / "data"
    write_tiny_dataset(root)
    meta = json.loads((root / "transforms.json").read_text())
    for frame in meta["frames"]:
        for name in OPTIONAL_PROPERTIES:
            frame.pop(REGISTRY[name].file_key)
    (root / "transforms.json").write_text(json.dumps(meta))
    return root


def run(data: Path, annotations: Optional[Path], **options):
    config = LabelDatasetConfig(data=data, annotations=annotations, workers=1, **{**ONLY_SEMANTICS, **options})
    return label_dataset(config, load_transforms(data))


def labelled(data: Path) -> Dict[str, np.ndarray]:
    """Class ids per frame name, for the frames that list semantics."""
    meta = json.loads((data / "transforms.json").read_text())
    return {Path(frame["file_path"]).name: np.asarray(Image.open(data / frame["semantics_file_path"]))
            for frame in meta["frames"] if "semantics_file_path" in frame}


def box(x0: int, x1: int, y0: int, y1: int) -> List[float]:
    """The polygon along the pixel edges of columns x0..x1-1, rows y0..y1-1 (COCO's flat vertex list)."""
    return [x0, y0, x1, y0, x1, y1, x0, y1]


def box_mask(x0: int, x1: int, y0: int, y1: int) -> np.ndarray:
    mask = np.zeros((HEIGHT, WIDTH), bool)
    mask[y0:y1, x0:x1] = True
    return mask


L_SHAPE = [0, 6, 5, 6, 5, 9, 3, 9, 3, 12, 0, 12]
"""A pixel-aligned L: columns 0-4 of rows 6-8, and columns 0-2 of rows 9-11."""


def l_mask() -> np.ndarray:
    return box_mask(0, 5, 6, 9) | box_mask(0, 3, 9, 12)


def runs(mask: np.ndarray) -> List[int]:
    """Uncompressed COCO RLE counts: column-major run lengths, starting with a run of zeros."""
    flat = mask.flatten(order="F").astype(int)
    changes = np.flatnonzero(np.diff(flat)) + 1
    bounds = np.concatenate([[0], changes, [flat.size]])
    counts = np.diff(bounds).tolist()
    return [0, *counts] if flat[0] else counts


def compressed(mask: np.ndarray) -> Dict:
    rle = coco_mask.encode(np.asfortranarray(mask.astype(np.uint8)))
    return {"size": rle["size"], "counts": rle["counts"].decode("ascii")}


def coco_file(path: Path, images: List[Dict], annotations: List[Dict], categories: List[Dict]) -> Path:
    for number, annotation in enumerate(annotations):
        annotation.setdefault("id", number + 1)
        annotation.setdefault("iscrowd", 0)
    path.write_text(json.dumps({"images": images, "annotations": annotations, "categories": categories}))
    return path


def image(image_id: int, name: str, width: int = WIDTH, height: int = HEIGHT) -> Dict:
    return {"id": image_id, "file_name": name, "width": width, "height": height}


CATEGORIES = [{"id": 1, "name": "wall"}, {"id": 2, "name": "floor"}, {"id": 9, "name": "chair"},
              {"id": 5, "name": "table"}]


def test_coco_polygons_and_both_rle_encodings_import_exactly(data: Path, tmp_path: Path) -> None:
    wall, floor, chair = box_mask(0, 16, 0, 6), l_mask(), box_mask(9, 14, 7, 11)
    annotations = [
        {"image_id": 1, "category_id": 1, "segmentation": [box(0, 16, 0, 6)]},  # along the image border
        {"image_id": 1, "category_id": 2, "segmentation": [L_SHAPE]},
        {"image_id": 1, "category_id": 9, "segmentation": [box(9, 12, 7, 11), box(12, 14, 7, 11)]},  # two parts
        {"image_id": 2, "category_id": 5, "segmentation": {"size": [HEIGHT, WIDTH], "counts": runs(chair)}},
        {"image_id": 2, "category_id": 2, "segmentation": compressed(floor)},
    ]
    source = coco_file(tmp_path / "coco.json", [image(1, "images/frame_001.png"), image(2, "frame_004.png")],
                       annotations, CATEGORIES)
    report = run(data, source)

    classes = json.loads((data / "transforms.json").read_text())["semantic_classes"]
    assert classes == [*CLASSES, "chair"]  # matched by name; the new one appended (id 4)
    expected_1 = np.full((HEIGHT, WIDTH), 255)
    expected_1[wall], expected_1[floor], expected_1[chair] = 1, 2, 4
    expected_4 = np.full((HEIGHT, WIDTH), 255)
    expected_4[chair], expected_4[floor] = 3, 2
    result = labelled(data)
    assert set(result) == {"frame_001.png", "frame_004.png"}
    np.testing.assert_array_equal(result["frame_001.png"], expected_1)
    np.testing.assert_array_equal(result["frame_004.png"], expected_4)
    assert report.outcomes["semantics"] == {LABELLED: 2, f"skipped: no annotation in {source}": 4}


def test_smaller_shape_wins_and_unannotated_frames_get_no_semantics(data: Path, tmp_path: Path) -> None:
    """A table drawn before the wall it stands against, a chair inside the table: each smaller shape stays on top."""
    annotations = [
        {"image_id": 1, "category_id": 9, "segmentation": [box(6, 8, 5, 7)]},
        {"image_id": 1, "category_id": 5, "segmentation": [box(4, 12, 4, 10)]},
        {"image_id": 1, "category_id": 1, "segmentation": [box(0, 16, 0, 12)]},
    ]
    run(data, coco_file(tmp_path / "coco.json", [image(1, "frame_002.png")], annotations, CATEGORIES))
    expected = np.full((HEIGHT, WIDTH), 1)
    expected[box_mask(4, 12, 4, 10)] = 3
    expected[box_mask(6, 8, 5, 7)] = 4
    result = labelled(data)
    assert list(result) == ["frame_002.png"]  # the five other frames list no semantics file
    np.testing.assert_array_equal(result["frame_002.png"], expected)
    outputs = SSNeRFDataParserConfig(data=data).setup().get_dataparser_outputs("train")
    assert "semantics" in outputs.metadata["available_properties"]  # semantics on a subset of frames trains


def labelme_file(path: Path, image_path: str, shapes: List[Dict], size=(WIDTH, HEIGHT)) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"version": "5.4.1", "flags": {}, "shapes": shapes, "imagePath": image_path,
                                "imageData": None, "imageWidth": size[0], "imageHeight": size[1]}))
    return path


def shape(label: str, points: List, kind: str = "polygon") -> Dict:
    return {"label": label, "points": points, "group_id": None, "shape_type": kind, "flags": {}}


def test_labelme_folder_polygon_rectangle_circle(data: Path, tmp_path: Path) -> None:
    folder = tmp_path / "labelme"
    labelme_file(folder / "a.json", "../data/images/frame_000.png", [  # relative to the JSON file
        shape("floor", np.reshape(L_SHAPE, (-1, 2)).tolist()),
        shape("table", [[14, 5], [9, 1]], "rectangle"),  # any two opposite corners
        shape("wall", [[3, 2], [9, 9]], "line"),
        shape("wall", [[1, 1]], "point"),
    ])
    labelme_file(folder / "b.json", "somewhere\\else\\frame_005.png", [  # matched by file name
        shape("lamp", [[8.0, 6.0], [11.0, 6.0]], "circle"),
    ])
    report = run(data, folder)

    assert json.loads((data / "transforms.json").read_text())["semantic_classes"] == [*CLASSES, "lamp"]
    expected_0 = np.full((HEIGHT, WIDTH), 255)
    expected_0[l_mask()], expected_0[box_mask(9, 14, 1, 5)] = 2, 3
    cols, rows = np.meshgrid(np.arange(WIDTH) + 0.5, np.arange(HEIGHT) + 0.5)
    circle = (cols - 8.0) ** 2 + (rows - 6.0) ** 2 <= 3.0**2
    expected_5 = np.where(circle, 4, 255)
    result = labelled(data)
    np.testing.assert_array_equal(result["frame_000.png"], expected_0)
    np.testing.assert_array_equal(result["frame_005.png"], expected_5)
    assert circle.sum() == 32  # pixel centres within 3 px of (8, 6): 8 per quadrant
    assert report.notes == [f"{folder}: skipped shapes that label no pixels (1 line, 1 point)."]
    record = json.loads((data / "transforms.json").read_text())["ssnerf_label"]["annotations"][-1]
    assert record["format"] == "labelme" and record["skipped_shapes"] == {"line": 1, "point": 1}


def test_fixed_class_list_and_colours_for_appended_classes(data: Path, tmp_path: Path, edit_transforms) -> None:
    coco = coco_file(tmp_path / "coco.json", [image(1, "frame_003.png")],
                     [{"image_id": 1, "category_id": 9, "segmentation": [box(0, 4, 0, 4)]}], CATEGORIES)
    fixed = shutil.copytree(data, tmp_path / "fixed")
    run(fixed, coco, semantic_classes=["chair", "wall"])  # the list is used as given: chair = 0
    assert json.loads((fixed / "transforms.json").read_text())["semantic_classes"] == ["chair", "wall"]
    assert labelled(fixed)["frame_003.png"][0, 0] == 0

    colours = [[0, 0, 0], [200, 10, 10], [10, 200, 10], [10, 10, 200]]
    edit_transforms(data, lambda meta: meta.update(semantic_colors=colours))
    run(data, coco)
    meta = json.loads((data / "transforms.json").read_text())
    assert meta["semantic_classes"] == [*CLASSES, "chair"]
    palette = (default_palette(5) * 255).round().int().tolist()
    assert meta["semantic_colors"] == [*colours, palette[4]]  # what the model shows an uncoloured class 4 in


def test_provenance_and_a_rerun_takes_the_edited_annotations(data: Path, tmp_path: Path) -> None:
    coco = tmp_path / "coco.json"
    coco_file(coco, [image(1, "frame_001.png"), image(2, "frame_002.png")],
              [{"image_id": 1, "category_id": 1, "segmentation": [box(0, 4, 0, 4)]},
               {"image_id": 2, "category_id": 2, "bbox": [0, 0, 3, 3]}], CATEGORIES)  # a box only: no pixels
    run(data, coco, edges=True)
    record = json.loads((data / "transforms.json").read_text())["ssnerf_label"]
    first_import = {
        "source": str(coco.resolve()), "format": "coco",
        "frames": {"images/frame_001.png": str(coco.resolve())},
        "skipped_shapes": {"annotation without segmentation": 1},
    }
    assert record["annotations"] == [first_import]
    assert record["semantics"].startswith(f"copied from {coco} (coco")
    assert set(record) == {"tool", "semantics", "edges", "annotations"}

    coco_file(coco, [image(1, "frame_001.png")],
              [{"image_id": 1, "category_id": 2, "segmentation": [box(0, 2, 0, 2)]}], CATEGORIES)
    report = run(data, coco)  # no --relabel: the edited file's labels go over the earlier ones
    assert report.outcomes["semantics"][LABELLED] == 1
    assert labelled(data)["frame_001.png"][0, 0] == 2 and labelled(data)["frame_001.png"][3, 3] == 1
    assert labelled(data)["frame_001.png"][5, 5] == 255
    imports = json.loads((data / "transforms.json").read_text())["ssnerf_label"]["annotations"]
    assert len(imports) == 2 and imports[0] == first_import and "skipped_shapes" not in imports[1]
    run(data, coco, relabel=True)  # --relabel: this file alone
    assert labelled(data)["frame_001.png"][0, 0] == 2 and labelled(data)["frame_001.png"][3, 3] == 255
    assert len(json.loads((data / "transforms.json").read_text())["ssnerf_label"]["annotations"]) == 1


def test_mask_folder_through_annotations(data: Path, tmp_path: Path) -> None:
    """`--annotations FOLDER_OF_PNGS` reads class-id masks as --semantics-dir does."""
    (tmp_path / "masks").mkdir()
    ids = np.where(l_mask(), 2, 255).astype(np.uint8)
    Image.fromarray(ids).save(tmp_path / "masks" / "frame_002.png")
    run(data, tmp_path / "masks")
    np.testing.assert_array_equal(labelled(data)["frame_002.png"], ids)
    record = json.loads((data / "transforms.json").read_text())["ssnerf_label"]["annotations"][-1]
    assert record["format"] == "masks" and list(record["frames"]) == ["images/frame_002.png"]


def test_clicks_grown_over_the_image_with_semantics_grow(data: Path, tmp_path: Path) -> None:
    """`--semantics-grow` fills the image segment a click falls in (here the frame's left half, one colour); the
    provenance says so."""
    halves = np.zeros((HEIGHT, WIDTH, 3), np.uint8)
    halves[:, : WIDTH // 2], halves[:, WIDTH // 2 :] = (220, 30, 30), (30, 30, 220)
    Image.fromarray(halves).save(data / "images" / "frame_002.png")
    (tmp_path / "clicks").mkdir()
    clicks = np.full((HEIGHT, WIDTH), 255, np.uint8)
    clicks[3, 2] = 2
    Image.fromarray(clicks).save(tmp_path / "clicks" / "frame_002.png")
    run(data, tmp_path / "clicks", label_options=LabelOptions(semantics_grow=300))
    grown = labelled(data)["frame_002.png"]
    assert (grown[:, : WIDTH // 2 - 1] == 2).all() and (grown[:, WIDTH // 2 + 1 :] == 255).all()
    record = json.loads((data / "transforms.json").read_text())["ssnerf_label"]
    assert "grown over the image's segments" in record["semantics"]


def test_class_list_alone_is_written_and_the_dataset_checks(data: Path, edit_transforms, capsys) -> None:
    """Declaring classes before painting strokes: no frame has semantics, yet the list (and colours) is written."""
    edit_transforms(data, lambda meta: meta.update(semantic_colors=[[0, 0, 0], [9, 9, 9], [8, 8, 8], [7, 7, 7]]))
    report = label_main(LabelDatasetConfig(data=data, semantic_classes=["wall", "floor", "chair"], workers=1,
                                           **ONLY_SEMANTICS))
    assert report.labelled("semantics") == 0
    meta = json.loads((data / "transforms.json").read_text())
    assert meta["semantic_classes"] == ["wall", "floor", "chair"]
    assert meta["semantic_colors"] == [[0, 0, 0], [9, 9, 9], [8, 8, 8]]
    assert not any("semantics_file_path" in frame for frame in meta["frames"])
    assert check_main(CheckConfig(data=data)) == 0
    outputs = SSNeRFDataParserConfig(data=data).setup().get_dataparser_outputs("train")
    assert outputs.metadata["semantic_classes"] == ["wall", "floor", "chair"]


# Bad annotations: one line naming the file and the fix, nothing written.


def bad_coco(**change) -> Callable[[Path, Path], List[str]]:
    """A COCO file for frame_001 with one shape, after `change` (images / annotation / categories overrides)."""

    def make(data: Path, folder: Path) -> List[str]:
        annotation = {"image_id": 1, "category_id": 1, "segmentation": [box(0, 4, 0, 4)], **change.get("shape", {})}
        coco_file(folder / "coco.json", change.get("images", [image(1, "frame_001.png")]), [annotation], CATEGORIES)
        return ["--annotations", str(folder / "coco.json"), *change.get("args", [])]

    return make


def write(name: str, text: str) -> Callable[[Path, Path], List[str]]:
    def make(data: Path, folder: Path) -> List[str]:
        (folder / name).write_text(text)
        return ["--annotations", str(folder / name)]
    return make


def bad_labelme(data: Path, folder: Path) -> List[str]:
    labelme_file(folder / "lm" / "a.json", "frame_000.png", [shape("wall", [[0, 0], [4, 0], [2, 40]])])
    return ["--annotations", str(folder / "lm")]


BAD: Dict[str, tuple] = {
    # name: (write the annotations and return the arguments; words the one line must hold)
    "malformed JSON": (write("coco.json", '{"images": [{"id": 1,'), ["coco.json", "not valid JSON", "Re-export"]),
    "image matching no frame": (bad_coco(images=[image(1, "photos/IMG_0001.jpg")]),
                                ["coco.json", "IMG_0001.jpg", "matches no frame"]),
    "polygon outside the image": (bad_coco(shape={"segmentation": [[0, 0, 30, 0, 30, 5]]}),
                                  ["coco.json", "annotation 1", "outside the 16x12 image"]),
    "labelme polygon outside the image": (bad_labelme, ["a.json", "shape 0", "outside the 16x12 image"]),
    "category outside fixed --semantic-classes": (bad_coco(args=["--semantic-classes", "floor", "table"]),
                                                  ["coco.json", "'wall'", "not in --semantic-classes"]),
    "RLE of the wrong size": (bad_coco(shape={"segmentation": compressed(np.ones((24, 32), bool))}),
                              ["coco.json", "RLE size [24, 32]", "[12, 16]"]),
    "RLE counts not covering the image": (
        bad_coco(shape={"segmentation": {"size": [HEIGHT, WIDTH], "counts": [5, 10]}}),
        ["coco.json", "cover 15 pixels", "Re-export"]),
    "COCO image of another size": (bad_coco(images=[image(1, "frame_001.png", 32, 24)]),
                                   ["coco.json", "32x24", "16x12"]),
    "unknown file type": (write("labels.xml", "<annotation/>"), ["labels.xml", "convert other formats to COCO"]),
    "neither COCO nor labelme": (write("other.json", '{"objects": []}'), ["other.json", "neither a COCO"]),
    "negative --semantics-grow": (bad_coco(args=["--semantics-grow", "-5"]), ["--semantics-grow -5", "0 (off)"]),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_annotations_one_line_nothing_written(case: str, data: Path, tmp_path: Path, capsys,
                                                  monkeypatch) -> None:
    make, words = BAD[case]
    (tmp_path / "annotations").mkdir()
    ssnerf_label_refuses(data, make(data, tmp_path / "annotations"), words, capsys, monkeypatch)


def test_two_sources_and_ambiguous_names_are_refused(data: Path, tmp_path: Path, edit_transforms) -> None:
    coco = bad_coco()(data, tmp_path)
    with pytest.raises(DatasetInputError, match="--annotations and --semantics-dir both given"):
        run(data, Path(coco[1]), semantics_dir=tmp_path)
    (data / "more").mkdir()
    (data / "more" / "frame_001.png").write_bytes((data / "images" / "frame_001.png").read_bytes())

    def add_frame(meta: Dict) -> None:
        meta["frames"].append({**meta["frames"][1], "file_path": "more/frame_001.png"})
        meta["train_filenames"].append("more/frame_001.png")

    edit_transforms(data, add_frame)
    with pytest.raises(DatasetInputError, match="matches frames images/frame_001.png and more/frame_001.png"):
        run(data, Path(coco[1]))
    coco_file(tmp_path / "coco.json", [image(1, "more/frame_001.png")],  # its relative path tells them apart
              [{"image_id": 1, "category_id": 1, "segmentation": [box(0, 4, 0, 4)]}], CATEGORIES)
    run(data, tmp_path / "coco.json")
    meta = json.loads((data / "transforms.json").read_text())
    assert [frame["file_path"] for frame in meta["frames"] if "semantics_file_path" in frame] == ["more/frame_001.png"]
