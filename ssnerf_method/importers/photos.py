"""Poses for a folder of photos or a video with COLMAP's own Python bindings (`pycolmap`) on the CPU, written as the
dataset `ns-process-data images` writes: `images/` (and `images_2/`, `images_4/`, `images_8/`), `colmap/sparse/0`,
`transforms.json` and `sparse_pc.ply`, so every nerfstudio tool reads it. No COLMAP or ffmpeg binary is needed.

The stages (gather, extract, match, map, write, downscale) report through a `ProcessObserver`, which the console
script draws as progress bars. Everything is written into a `StagedOutputFolder`: a failed run leaves nothing.
"""

from __future__ import annotations

import json
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Dict, List, Literal, Optional, Tuple

import cv2
import numpy as np
from PIL import Image

from ssnerf_method.data.io import DatasetInputError, StagedOutputFolder, write_json_atomic
from ssnerf_method.importers.writer import IMAGE_SUFFIXES, check_destination, list_images

Matching = Literal["exhaustive", "sequential"]
MIN_IMAGES = 3
"""Fewest images structure from motion can pose (two to start, one more to check them)."""
EXIF_ORIENTATION = 0x0112
"""EXIF tag of a photo's rotation; a rotated photo is rewritten upright, since COLMAP reads the stored pixels."""


class ProcessObserver:
    """What `process_capture` reports as it goes; the console script draws it, tests can ignore it."""

    def stage(self, name: str, total: Optional[int]) -> None:
        """A stage starts; `total` steps follow (None: no count, e.g. matching)."""

    def advance(self, steps: int = 1) -> None:
        """The current stage made `steps` more steps."""

    def done(self, name: str, seconds: float) -> None:
        """The stage finished after `seconds`."""


@dataclass
class ProcessOptions:
    """What the structure from motion does, for photos and video alike."""

    matching: Matching = "exhaustive"
    """Which image pairs are matched: every pair (`exhaustive`, photos in any order) or each image with its
    `--overlap` neighbours in file order (`sequential`, a video or a walk: linear in the number of images)."""
    overlap: int = 10
    """Neighbours each image is matched with under `--matching sequential`."""
    max_image_size: int = 1600
    """Longest side (pixels) SIFT sees; larger photos are shrunk for feature extraction only (COLMAP's default is
    3200: about 3x slower on a CPU, for poses that a NeRF at nerfstudio's 1600-pixel training size does not need)."""
    max_num_features: int = 8192
    """SIFT features kept per image (COLMAP's default). Fewer make matching and mapping faster."""
    num_downscales: int = 3
    """Half-size copies to write, as ns-process-data does (`images_2/`, `images_4/`, `images_8/` for 3); nerfstudio
    trains on the first one whose longer side is at most 1600 pixels."""
    min_registered: float = 0.5
    """Fewest images that must be posed, as a share of all; fewer stop the run with what to do."""
    seed: int = 0
    """Seed of COLMAP's random choices (the same capture gives the same poses)."""
    overwrite: bool = False
    """Replace an existing, non-empty output folder (only once the new one is complete)."""


@dataclass
class ProcessReport:
    """What a run did: frames posed, frames left out, reprojection error and each stage's time."""

    output_dir: Path
    num_images: int
    registered: List[str]
    unregistered: List[str]
    num_points: int
    reprojection_error_px: float
    seconds: Dict[str, float] = field(default_factory=dict)


def list_photos(folder: Path) -> List[Path]:
    """The images of `folder` (sorted by name); one line why when it is missing, empty or too small."""
    if not folder.is_dir():
        raise DatasetInputError(f"{folder}: not a folder. Pass the folder that holds your photos "
                                "(ssnerf-process video CLIP for a video).")
    photos = list_images(folder)
    if not photos:
        raise DatasetInputError(f"{folder}: holds no images ({', '.join(IMAGE_SUFFIXES)}). Put the photos of one "
                                "scene in it.")
    if len(photos) < MIN_IMAGES:
        raise DatasetInputError(f"{folder}: {len(photos)} image(s); structure from motion needs at least {MIN_IMAGES}. "
                                "Take more photos that overlap (30-100 for a room).")
    return photos


def _upright(path: Path) -> Tuple[Optional[np.ndarray], Tuple[int, int]]:
    """The image as stored, upright: (pixels to write when its EXIF rotates it, else None; (width, height))."""
    try:
        with Image.open(path) as image:
            orientation = image.getexif().get(EXIF_ORIENTATION, 1)
            size = image.size
    except (OSError, ValueError) as err:
        raise DatasetInputError(f"{path}: not a readable image ({err}). Remove it or re-export it as JPEG.") from err
    if orientation in (None, 1):
        return None, size
    pixels = cv2.imread(str(path), cv2.IMREAD_COLOR)  # applies the EXIF rotation
    if pixels is None:
        raise DatasetInputError(f"{path}: not a readable image. Remove it or re-export it as JPEG.")
    return pixels, (pixels.shape[1], pixels.shape[0])


def gather_photos(folder: Path, images: Path, observer: ProcessObserver) -> Dict[str, str]:
    """Copy `folder`'s photos to `images/frame_00001.jpg`, ... (nerfstudio's names), upright; returns new name ->
    original name. All must have one size: nerfstudio's transforms.json has one camera."""
    photos = list_photos(folder)
    observer.stage("Copying photos", len(photos))
    images.mkdir(parents=True)
    names: Dict[str, str] = {}
    first_size: Optional[Tuple[int, int]] = None
    for index, photo in enumerate(photos, start=1):
        pixels, size = _upright(photo)
        if first_size is None:
            first_size = size
        elif size != first_size:
            raise DatasetInputError(
                f"{photo}: {size[0]}x{size[1]} pixels, but {photos[0].name} is {first_size[0]}x{first_size[1]}. Give "
                "one camera's photos at one size (resize or crop the others, or process each size separately).")
        name = f"frame_{index:05d}{photo.suffix.lower()}"
        if pixels is None:
            shutil.copyfile(photo, images / name)
        else:
            cv2.imwrite(str(images / name), pixels, [cv2.IMWRITE_JPEG_QUALITY, 95])
        names[name] = photo.name
        observer.advance()
    return names


def gather_video(video: Path, images: Path, num_frames: int, observer: ProcessObserver) -> Dict[str, str]:
    """About `num_frames` frames spread evenly over `video`, as `images/frame_00001.jpg`, ...; returns new name ->
    "VIDEO@frame"."""
    if not video.is_file():
        raise DatasetInputError(f"{video}: no such file. Pass a video file (ssnerf-process images FOLDER for photos).")
    capture = cv2.VideoCapture(str(video))
    total = int(capture.get(cv2.CAP_PROP_FRAME_COUNT)) if capture.isOpened() else 0
    if total <= 0:
        capture.release()
        raise DatasetInputError(f"{video}: not a video OpenCV can read. Re-encode it as H.264 MP4 (e.g. ffmpeg -i "
                                f"{video.name} -c:v libx264 clip.mp4) or extract its frames into a folder and run "
                                "ssnerf-process images on it.")
    wanted = set(np.linspace(0, total - 1, min(num_frames, total)).round().astype(int).tolist())
    observer.stage("Reading video frames", len(wanted))
    images.mkdir(parents=True)
    names: Dict[str, str] = {}
    index = 0
    try:
        while index < total and len(names) < len(wanted):
            ok, frame = capture.read()
            if not ok:
                break
            if index in wanted:
                name = f"frame_{len(names) + 1:05d}.jpg"
                cv2.imwrite(str(images / name), frame, [cv2.IMWRITE_JPEG_QUALITY, 95])
                names[name] = f"{video.name}@{index}"
                observer.advance()
            index += 1
    finally:
        capture.release()
    if len(names) < MIN_IMAGES:
        raise DatasetInputError(f"{video}: only {len(names)} frame(s) could be read; structure from motion needs at "
                                f"least {MIN_IMAGES}. Re-encode it as H.264 MP4 or pass a longer video.")
    return names


def _quiet_colmap() -> None:
    """COLMAP logs every step to stderr; keep its errors only (the stages draw their own progress)."""
    import pycolmap

    pycolmap.logging.minloglevel = 2


def extract_and_match(database: Path, images: Path, options: ProcessOptions, observer: ProcessObserver) -> None:
    """SIFT features of every image (one shared OPENCV camera, as ns-process-data's default) and their matches."""
    import pycolmap

    names = sorted(path.name for path in images.iterdir())
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.max_image_size = options.max_image_size
    extraction.sift.max_num_features = options.max_num_features
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = "OPENCV"
    observer.stage("Extracting features", len(names))
    chunk = max(1, len(names) // 20)
    for start in range(0, len(names), chunk):
        batch = names[start : start + chunk]
        pycolmap.extract_features(database, images, image_names=batch, camera_mode=pycolmap.CameraMode.SINGLE,
                                  reader_options=reader, extraction_options=extraction, device=pycolmap.Device.cpu)
        observer.advance(len(batch))
        reader.existing_camera_id = 1  # later batches share the first batch's camera (SINGLE holds per call only)
    observer.stage(f"Matching ({options.matching})", None)
    if options.matching == "sequential":
        pairing = pycolmap.SequentialPairingOptions()
        pairing.overlap = options.overlap
        pycolmap.match_sequential(database, pairing_options=pairing, device=pycolmap.Device.cpu)
    else:
        pycolmap.match_exhaustive(database, device=pycolmap.Device.cpu)


def reconstruct(database: Path, images: Path, sparse: Path, options: ProcessOptions, num_images: int,
                observer: ProcessObserver):
    """Incremental mapping; the model with the most posed images (a `pycolmap.Reconstruction`), or None."""
    import pycolmap

    mapping = pycolmap.IncrementalPipelineOptions()
    mapping.random_seed = options.seed
    mapping.ba_global_function_tolerance = 1e-6  # as ns-process-data passes to COLMAP: global BA stops earlier
    observer.stage("Posing images (incremental mapping)", num_images)
    models = pycolmap.incremental_mapping(database, images, sparse, mapping,
                                          initial_image_pair_callback=lambda: observer.advance(2),
                                          next_image_callback=lambda: observer.advance(1))
    return max(models.values(), key=lambda model: model.num_reg_images(), default=None)


def too_few_registered(source: Path, posed: int, total: int, matching: Matching, video: bool) -> DatasetInputError:
    """The one line for a capture that mostly did not pose: how many did, and what to change."""
    advice = ("Take the photos closer together (each part of the scene in 3 or more photos, neighbours sharing about "
              "two thirds of the view), avoid blur and blank walls")
    if video:
        advice = ("Move the camera more slowly, keep the scene textured and in focus, or take more frames "
                  "(--num-frames)")
    elif matching == "exhaustive":
        advice += "; photos taken along a path can also try --matching sequential"
    return DatasetInputError(f"{source}: only {posed} of {total} images could be posed. {advice}.")


def downscale(images: Path, factors: List[int], observer: ProcessObserver) -> None:
    """`images_<f>/` copies at 1/f size (area averaging; sizes truncated as nerfstudio's cameras are rescaled)."""
    files = sorted(images.iterdir())
    observer.stage("Writing downscaled copies", len(files) * len(factors))
    for factor in factors:
        target = images.parent / f"images_{factor}"
        target.mkdir()
        for path in files:
            pixels = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
            small = cv2.resize(pixels, (pixels.shape[1] // factor, pixels.shape[0] // factor),
                               interpolation=cv2.INTER_AREA)
            cv2.imwrite(str(target / path.name), small, [cv2.IMWRITE_JPEG_QUALITY, 95])
            observer.advance()


def process_capture(source: Path, output_dir: Path, options: ProcessOptions,
                    gather: Callable[[Path, ProcessObserver], Dict[str, str]], video: bool = False,
                    observer: Optional[ProcessObserver] = None) -> ProcessReport:
    """Gather the images (`gather(images_folder, observer)`), pose them and write the nerfstudio dataset into
    `output_dir`, moved into place only when every stage succeeded."""
    from nerfstudio.process_data.colmap_utils import colmap_to_json

    observer = observer or ProcessObserver()
    check_destination(source if source.is_dir() else source.parent, output_dir)
    if (output_dir / "transforms.json").is_file() and not options.overwrite:
        raise DatasetInputError(f"{output_dir}: already holds a dataset (transforms.json). Pass --overwrite to "
                                "replace it, or pick another output folder.")
    _quiet_colmap()
    seconds: Dict[str, float] = {}

    def timed(name: str, run: Callable[[], object]) -> object:
        start = time.perf_counter()
        result = run()
        seconds[name] = round(time.perf_counter() - start, 2)
        observer.done(name, seconds[name])
        return result

    with StagedOutputFolder(output_dir, options.overwrite) as staging:
        images = staging / "images"
        names: Dict[str, str] = timed("gather", lambda: gather(images, observer))  # type: ignore[assignment]
        colmap = staging / "colmap"
        sparse = colmap / "sparse"
        sparse.mkdir(parents=True)
        database = colmap / "database.db"
        timed("features and matching", lambda: extract_and_match(database, images, options, observer))
        model = timed("mapping", lambda: reconstruct(database, images, sparse, options, len(names), observer))
        posed = model.num_reg_images() if model is not None else 0  # type: ignore[attr-defined]
        if posed < max(MIN_IMAGES, options.min_registered * len(names)):
            raise too_few_registered(source, posed, len(names), options.matching, video)
        for old in sparse.iterdir():  # keep the chosen model only, as sparse/0 (where nerfstudio looks)
            shutil.rmtree(old)
        (sparse / "0").mkdir()
        model.write(sparse / "0")  # type: ignore[attr-defined]
        timed("transforms.json", lambda: colmap_to_json(sparse / "0", staging))
        meta = json.loads((staging / "transforms.json").read_text())
        meta["frames"] = sorted(meta["frames"], key=lambda frame: frame["file_path"])
        write_json_atomic(staging / "transforms.json", meta)
        factors = [2**level for level in range(1, options.num_downscales + 1)]
        if factors:
            timed("downscale", lambda: downscale(images, factors, observer))
        registered = sorted(Path(frame["file_path"]).name for frame in meta["frames"])
        posed_names = set(registered)
        report = ProcessReport(
            output_dir=output_dir, num_images=len(names), registered=[names[name] for name in registered],
            unregistered=[original for name, original in sorted(names.items()) if name not in posed_names],
            num_points=model.num_points3D(),  # type: ignore[attr-defined]
            reprojection_error_px=float(model.compute_mean_reprojection_error()),  # type: ignore[attr-defined]
            seconds=seconds)
    return report
