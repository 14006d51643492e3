"""`ssnerf-process`: poses from photos with pycolmap, and every bad capture ending in one line with nothing written.

The posable capture is the embedded room rendered with `--grain` (photo-like surface texture) as JPEG photos with no
transforms.json; `tests/test_own_data_path.py` runs the README's whole own-data block on the same kind of capture.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Callable, Dict, List

import numpy as np
import pytest
from PIL import Image

from ssnerf_method.evaluation.poses import pose_errors, poses_by_photo_order
from ssnerf_method.importers.photos import ProcessOptions, gather_photos, process_capture

from conftest import one_line_error, snapshot


@pytest.fixture
def capture(photo_capture: Path) -> Path:
    return photo_capture


def test_photos_are_posed_as_nerfstudio_lays_a_dataset_out(capture: Path, tmp_path: Path) -> None:
    dataset = tmp_path / "my_scene"
    report = process_capture(capture, dataset, ProcessOptions(num_downscales=2),
                             lambda images, observer: gather_photos(capture, images, observer))
    # COLMAP's multithreaded mapping is not reproducible: all 36 are posed here as a rule, but a CI run once split
    # them into models of 23 and 13. The contract: the largest model's frames, the rest listed, no fewer than half.
    assert len(report.registered) + len(report.unregistered) == 36 and len(report.registered) >= 18
    meta = json.loads((dataset / "transforms.json").read_text())
    assert meta["camera_model"] == "OPENCV" and (meta["w"], meta["h"]) == (256, 192)
    assert abs(meta["fl_x"] - 256 / 2 / np.tan(np.radians(37.5))) < 0.05 * meta["fl_x"]  # the true 75 deg FOV
    paths = [frame["file_path"] for frame in meta["frames"]]
    assert paths == sorted(paths) and len(paths) == len(report.registered)
    assert set(paths) <= {f"images/frame_{i:05d}.jpg" for i in range(1, 37)}
    for folder, size in (("images", (256, 192)), ("images_2", (128, 96)), ("images_4", (64, 48))):
        assert Image.open(dataset / folder / "frame_00001.jpg").size == size
    assert not (dataset / "images_8").exists()
    assert (dataset / "sparse_pc.ply").is_file() and (dataset / "colmap" / "sparse" / "0" / "images.bin").is_file()
    assert report.reprojection_error_px < 1.0
    errors = pose_errors(*poses_by_photo_order(capture.parent / "scene" / "transforms.json",
                                               dataset / "transforms.json"))
    assert np.median(errors.rotation_deg) <= 2.0 and np.median(errors.translation) <= 0.05, errors


def test_pose_errors_fail_for_wrong_poses(capture: Path) -> None:
    """The measure can fail: poses of other frames (shuffled) are far off after the best alignment."""
    scene = capture.parent / "scene"
    truth = np.stack([np.asarray(frame["transform_matrix"])
                      for frame in json.loads((scene / "transforms.json").read_text())["frames"]])
    assert np.median(pose_errors(truth, truth).rotation_deg) < 1e-6
    shuffled = pose_errors(truth, truth[np.random.default_rng(0).permutation(len(truth))])
    assert np.median(shuffled.rotation_deg) > 10 and np.median(shuffled.translation) > 0.1


def few(folder: Path) -> Path:
    folder.mkdir()
    for index in range(2):
        Image.new("RGB", (64, 48), (index * 50, 80, 90)).save(folder / f"photo_{index}.jpg")
    return folder


def noise(folder: Path) -> Path:
    """Four unrelated random images: features everywhere, no two images of one scene."""
    folder.mkdir()
    rng = np.random.default_rng(0)
    for index in range(4):
        pixels = np.repeat(np.repeat(rng.integers(0, 255, (48, 64, 3), dtype=np.uint8), 3, 0), 3, 1)
        Image.fromarray(pixels).save(folder / f"photo_{index}.jpg", quality=95)
    return folder


def mixed(folder: Path) -> Path:
    folder.mkdir()
    for index, size in enumerate(((64, 48), (64, 48), (48, 64))):
        Image.new("RGB", size, (10, 20, 30)).save(folder / f"photo_{index}.jpg")
    return folder


def empty(folder: Path) -> Path:
    folder.mkdir()
    (folder / "notes.txt").write_text("no photos here")
    return folder


def bad_video(folder: Path) -> Path:
    folder.mkdir()
    (folder / "clip.mp4").write_text("not a video")
    return folder / "clip.mp4"


BAD_CAPTURES: Dict[str, tuple] = {
    # name: (subcommand, make the source from a new folder, extra arguments, words the one line must hold)
    "empty folder": ("images", empty, [], ["holds no images", "Put the photos"]),
    "fewer than 3 images": ("images", few, [], ["2 image(s)", "at least 3"]),
    "images that do not overlap": ("images", noise, [], ["could be posed", "closer together"]),
    "mixed sizes": ("images", mixed, [], ["photo_2.jpg", "48x64", "one size"]),
    "unreadable video": ("video", bad_video, [], ["clip.mp4", "not a video OpenCV can read", "H.264"]),
    "not a folder": ("images", lambda folder: folder / "missing", [], ["not a folder"]),
}


@pytest.mark.parametrize("case", list(BAD_CAPTURES), ids=list(BAD_CAPTURES))
def test_a_bad_capture_ends_in_one_line_and_writes_nothing(case: str, tmp_path: Path, capsys, monkeypatch) -> None:
    from ssnerf_method.cli import process

    subcommand, make, extra, words = BAD_CAPTURES[case]
    source = make(tmp_path / "source")
    output = tmp_path / "out" / "my_scene"
    before = snapshot(tmp_path)
    monkeypatch.setattr(sys, "argv", ["ssnerf-process", subcommand, str(source), str(output), *extra])
    with pytest.raises(SystemExit) as exit_info:
        process.entrypoint()
    assert exit_info.value.code == 1
    line = one_line_error(capsys.readouterr().err, "ssnerf-process", words)
    assert str(source) in line
    assert snapshot(tmp_path) == before  # no output folder, no staging folder left behind


def test_an_existing_dataset_is_kept_without_overwrite(capture: Path, tmp_path: Path, capsys, monkeypatch) -> None:
    from ssnerf_method.cli import process

    output = tmp_path / "my_scene"
    output.mkdir()
    (output / "transforms.json").write_text('{"frames": []}')
    before = snapshot(tmp_path)
    monkeypatch.setattr(sys, "argv", ["ssnerf-process", "images", str(capture), str(output)])
    with pytest.raises(SystemExit):
        process.entrypoint()
    one_line_error(capsys.readouterr().err, "ssnerf-process", [str(output), "already holds a dataset", "--overwrite"])
    assert snapshot(tmp_path) == before


def test_a_video_becomes_frames_posed_in_order(capture: Path, tmp_path: Path) -> None:
    import cv2

    from ssnerf_method.importers.photos import gather_video

    video = tmp_path / "clip.mp4"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), 10, (256, 192))
    photos: List[Path] = sorted(capture.iterdir())
    for photo in photos:
        writer.write(cv2.imread(str(photo)))
    writer.release()
    gather: Callable = lambda images, observer: gather_video(video, images, 36, observer)  # noqa: E731
    report = process_capture(video, tmp_path / "from_video", ProcessOptions(matching="sequential", num_downscales=0),
                             gather, video=True)
    assert len(report.registered) + len(report.unregistered) == 36
    assert len(report.registered) >= 18, report.unregistered  # MPEG-4 part 2 blurs it: 28 of 36 posed here
    indices = [int(name.split("@")[1]) for name in report.registered]  # frames of the video, in its order
    assert indices == sorted(set(indices)) and set(indices) <= set(range(36))
