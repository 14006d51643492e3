"""COCO instance-segmentation files (`images`, `annotations`, `categories`) as `Annotations`.

Each image is matched to a frame by its `file_name` (`FrameIndex`) and must have the frame's image size. An
annotation's `segmentation` is polygons (flat vertex lists, rasterised by pycocotools) or a run-length encoding,
compressed (`counts` a string) or not (`counts` a list), whose `size` must be the image's [height, width].
Categories become class names; annotations without a segmentation (boxes only) label no pixels and are counted as
skipped.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Dict, List

from pycocotools import mask as coco_mask

from ssnerf_method.data.io import DatasetInputError
from ssnerf_method.importers.annotations import Annotations, FrameIndex, FrameShapes, Shape, polygon_rle


def read_coco(path: Path, content: Dict[str, Any], index: FrameIndex) -> Annotations:
    """The annotations of a parsed COCO file at `path`, every image matched to a frame and every shape checked."""
    for key in ("images", "annotations", "categories"):
        if not isinstance(content.get(key), list):
            raise DatasetInputError(f"{path}: COCO file without a \"{key}\" list. Re-export it as COCO instance "
                                    "segmentation.")
    categories: Dict[Any, str] = {}
    for category in content["categories"]:
        if not isinstance(category, dict) or "id" not in category or not isinstance(category.get("name"), str):
            raise DatasetInputError(f"{path}: a category without an \"id\" and a \"name\". Fix the categories list.")
        categories[category["id"]] = category["name"]
    annotations = Annotations(path, "coco", labels=list(dict.fromkeys(categories.values())))  # in the file's order

    images: Dict[Any, str] = {}
    for image in content["images"]:
        if not isinstance(image, dict) or "id" not in image or not isinstance(image.get("file_name"), str):
            raise DatasetInputError(f"{path}: an image without an \"id\" and a \"file_name\". Fix the images list.")
        file_path = index.find(image["file_name"], path, entry=f" (image id {image['id']})")
        width, height = index.size(file_path)
        if (image.get("width", width), image.get("height", height)) != (width, height):
            raise DatasetInputError(
                f"{path}: image {image['file_name']!r} is {image.get('width')}x{image.get('height')} but frame "
                f"{file_path} is {width}x{height}. Annotate the dataset's images (or re-export at their size)."
            )
        images[image["id"]] = file_path
        annotations.frames[file_path] = FrameShapes(path)

    for number, annotation in enumerate(content["annotations"]):
        where = f"{path}: annotation {annotation.get('id', number) if isinstance(annotation, dict) else number}"
        if not isinstance(annotation, dict) or annotation.get("image_id") not in images:
            raise DatasetInputError(f"{where} names no image of the file's \"images\". Fix its image_id.")
        if annotation.get("category_id") not in categories:
            raise DatasetInputError(f"{where} names no category of the file's \"categories\". Fix its category_id.")
        file_path = images[annotation["image_id"]]
        width, height = index.size(file_path)
        segmentation = annotation.get("segmentation")
        if not segmentation:
            annotations.skipped["annotation without segmentation"] += 1
            continue
        where += f" (frame {file_path})"
        if isinstance(segmentation, list):
            rle = polygon_rle(segmentation, width, height, where)
        elif isinstance(segmentation, dict):
            rle = run_length(segmentation, width, height, where)
        else:
            raise DatasetInputError(f"{where}: segmentation is neither polygons nor an RLE. Re-export the file.")
        annotations.frames[file_path].shapes.append(Shape(categories[annotation["category_id"]], rle))
    return annotations


def run_length(segmentation: Dict[str, Any], width: int, height: int, where: str) -> Dict[str, Any]:
    """A COCO RLE (compressed or not) checked against the frame's image size, as a compressed RLE."""
    size, counts = segmentation.get("size"), segmentation.get("counts")
    if size != [height, width]:
        raise DatasetInputError(
            f"{where}: RLE size {size} is not the image's [height, width] = [{height}, {width}]. Re-export the mask at "
            "the image's size."
        )
    if isinstance(counts, str):
        runs = compressed_counts(counts)
    elif isinstance(counts, list) and all(isinstance(count, int) for count in counts):
        runs = counts
    else:
        raise DatasetInputError(f"{where}: RLE counts are neither a string nor a list of integers. Re-export it.")
    if any(run < 0 for run in runs) or sum(runs) != height * width:
        raise DatasetInputError(
            f"{where}: RLE counts cover {sum(runs)} pixels (or hold a negative run), not the image's {height * width}. "
            "Re-export the mask."
        )
    if isinstance(counts, str):
        return {"size": [height, width], "counts": counts.encode("ascii")}
    return coco_mask.frPyObjects({"size": [height, width], "counts": counts}, height, width)


def compressed_counts(counts: str) -> List[int]:
    """The run lengths of a compressed COCO RLE string (pycocotools' `rleFrString`), only to check that they cover
    the image: 5-bit groups offset by 48, 0x20 continues, 0x10 in the last group is the sign, and from the third run
    on each is stored as the difference to the run two before."""
    if any(not 48 <= ord(character) < 112 for character in counts):
        return [-1]  # not an RLE string
    runs: List[int] = []
    position = 0
    while position < len(counts):
        value, shift, more = 0, 0, True
        while more:
            if position >= len(counts):
                return [-1]  # truncated in the middle of a number
            code = ord(counts[position]) - 48
            value |= (code & 0x1F) << shift
            more = bool(code & 0x20)
            position += 1
            shift += 5
            if not more and code & 0x10:
                value |= -1 << shift
        runs.append(value + runs[-2] if len(runs) > 2 else value)
    return runs
