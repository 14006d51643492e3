"""`ssnerf-import`: the paper's LLFF layout and Semantic-NeRF's Replica renders into the SS-NeRF dataset format.

Fixtures come from `source_layouts.py` (tiny datasets written from arrays in each source's own conventions). Checked:
cameras (a known 3D point lies on the ray nerfstudio generates through the pixel the source's camera model puts it
at), label encodings, class mappings, splits, downscaling, every bad input's error (leaving nothing behind), the CLI,
and a few training steps of ssnerf-lite on each import.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from ssnerf_method.cli.import_data import main
from ssnerf_method.data.classes import SEMANTIC_CLASSES, SEMANTIC_COLORS
from ssnerf_method.data.dataparser import SSNeRFDataParserConfig
from ssnerf_method.data.io import DatasetInputError
from ssnerf_method.data.transforms import load_transforms
from ssnerf_method.importers import (
    PaperLLFFImportConfig,
    SemanticNeRFImportConfig,
    import_paper_llff,
    import_semantic_nerf,
)
from ssnerf_method.importers.paper_llff import convert_normals, normals_axes_conversion
from ssnerf_method.label_tool.label_dataset import LabelDatasetConfig, label_dataset
from ssnerf_method.properties import OPTIONAL_PROPERTIES, labelled_properties

from source_layouts import (
    HEIGHT,
    LANDMARK,
    LLFF_LABEL_IDS,
    LLFF_NORMAL,
    REPLICA_CLASSES,
    WIDTH,
    SourceFixture,
    replica_semantics,
    write_paper_llff,
    write_semantic_nerf,
)
from test_training import lite_config, train

NYU = {name: index for index, name in enumerate(SEMANTIC_CLASSES)}


@pytest.fixture(scope="module", autouse=True)
def single_thread():
    """One torch thread: two cores shared with other jobs make torch's thread pool stall."""
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)


@pytest.fixture(scope="module")
def llff(tmp_path_factory) -> tuple[SourceFixture, Path]:
    root = tmp_path_factory.mktemp("llff")
    fixture = write_paper_llff(root / "src")
    import_paper_llff(PaperLLFFImportConfig(root / "src", root / "dst"))
    return fixture, root / "dst"


@pytest.fixture(scope="module")
def replica(tmp_path_factory) -> tuple[SourceFixture, Path]:
    """Semantic-NeRF fixture at 32x24 imported with --downscale 2 (16x12), its info_semantic.json beside it."""
    root = tmp_path_factory.mktemp("replica")
    fixture = write_semantic_nerf(root / "src")
    import_semantic_nerf(SemanticNeRFImportConfig(root / "src", root / "dst", downscale=2))
    return fixture, root / "dst"


def transforms(dst: Path) -> dict:
    return json.loads((dst / "transforms.json").read_text())


def read_png(path: Path) -> np.ndarray:
    with Image.open(path) as image:
        assert image.mode in ("L", "RGB", "I;16"), (path, image.mode)
        return np.asarray(image)


def landmark_ray_distance(dst: Path, index: int, pixel: tuple[float, float]) -> float:
    """Distance from `LANDMARK` (in nerfstudio's dataparser frame) to the ray through `pixel` of frame `index`."""
    parser = SSNeRFDataParserConfig(data=dst).setup()
    for split in ("train", "test"):
        outputs = parser.get_dataparser_outputs(split)
        names = [Path(path).name for path in outputs.image_filenames]
        if f"frame_{index:05d}.png" in names:
            break
    else:
        raise AssertionError(f"frame {index} in no split")
    transform = outputs.dataparser_transform.double()
    point = outputs.dataparser_scale * (transform[:, :3] @ torch.tensor(LANDMARK) + transform[:, 3])
    x, y = pixel
    rays = outputs.cameras.generate_rays(names.index(f"frame_{index:05d}.png"), coords=torch.tensor([[y, x]]))
    origin, direction = rays.origins[0].double(), rays.directions[0].double()
    along = torch.dot(point - origin, direction)
    assert along > 0, "landmark behind the camera"
    return float(torch.linalg.norm(point - origin - along * direction))


# --------------------------------------------------------------------------------------------------------------------
# cameras


def test_paper_llff_cameras_see_the_landmark_where_llff_does(llff) -> None:
    fixture, dst = llff
    assert len(fixture.pixels) == 2
    for index, (x, y) in fixture.pixels.items():
        assert 0 < x < WIDTH and 0 < y < HEIGHT
        assert landmark_ray_distance(dst, index, (x, y)) < 1e-4
        assert landmark_ray_distance(dst, index, (x + 1, y)) > 1e-2  # the check can tell a pixel apart
        assert landmark_ray_distance(dst, index, (x, y + 1)) > 1e-2


def test_semantic_nerf_cameras_see_the_landmark_where_opencv_does(replica) -> None:
    fixture, dst = replica
    for index, (x, y) in fixture.pixels.items():
        pixel = (x / 2, y / 2)  # imported with --downscale 2
        assert 0 < pixel[0] < WIDTH and 0 < pixel[1] < HEIGHT
        assert landmark_ray_distance(dst, index, pixel) < 1e-4
        assert landmark_ray_distance(dst, index, (pixel[0], pixel[1] + 1)) > 1e-2


# --------------------------------------------------------------------------------------------------------------------
# paper-llff labels, splits, options


def test_paper_llff_writes_our_format(llff) -> None:
    _, dst = llff
    meta = transforms(dst)
    assert (meta["w"], meta["h"], meta["cx"], meta["cy"]) == (WIDTH, HEIGHT, WIDTH / 2, HEIGHT / 2)
    assert meta["fl_x"] == meta["fl_y"] == pytest.approx(0.9 * WIDTH)  # hwf focal at 4x, scaled to the images
    assert meta["semantic_classes"] == list(SEMANTIC_CLASSES[1:])
    assert meta["semantic_colors"] == [list(color) for color in SEMANTIC_COLORS[1:]]
    assert meta["test_filenames"] == meta["val_filenames"] == ["images/frame_00000.png", "images/frame_00008.png"]
    assert meta["train_filenames"] == [f"images/frame_{i:05d}.png" for i in range(1, 10) if i != 8]
    assert meta["ssnerf_import"]["layout"] == "paper-llff"
    frame = meta["frames"][3]
    assert frame["file_path"] == "images/frame_00003.png" and "depth_file_path" not in frame
    labels = {key: read_png(dst / frame[f"{key}_file_path"]) for key in ("semantics", "normals", "shading")}
    labels.update({key: read_png(dst / frame[f"{key}_file_path"]) for key in ("keypoints", "edges")})
    # normals: the paper's (LUB) n = (a, b, c) is our (-a, b, c): the x code v becomes 255 - v
    assert labels["normals"].shape == (HEIGHT, WIDTH, 3)
    assert (labels["normals"] == (255 - LLFF_NORMAL[0], LLFF_NORMAL[1], LLFF_NORMAL[2])).all()
    # single-channel maps come from the first channel
    assert labels["semantics"].shape == (HEIGHT, WIDTH)
    assert (labels["semantics"][: HEIGHT // 2] == LLFF_LABEL_IDS[0]).all()
    assert (labels["semantics"][HEIGHT // 2 :] == LLFF_LABEL_IDS[1]).all()
    assert labels["shading"].shape == (HEIGHT, WIDTH)
    np.testing.assert_array_equal(labels["shading"][0], np.linspace(150, 250, WIDTH).astype(np.uint8))
    assert (labels["keypoints"] == 40).all() and (labels["edges"] == 20).all()


def test_normals_axes_codes() -> None:
    rgb = np.array([[[10, 20, 30]]], dtype=np.uint8)
    assert convert_normals(rgb, *normals_axes_conversion("RUB")).tolist() == [[[10, 20, 30]]]
    assert convert_normals(rgb, *normals_axes_conversion("lub")).tolist() == [[[245, 20, 30]]]
    # source +x points down, +y right, +z forward: our x = src y, our y = -src x, our z = -src z
    assert convert_normals(rgb, *normals_axes_conversion("DRF")).tolist() == [[[20, 245, 225]]]
    for bad in ("RU", "RRB", "XUB", "RUBB"):
        with pytest.raises(DatasetInputError, match="--normals-axes"):
            normals_axes_conversion(bad)


def test_paper_llff_normals_folder_choice_and_missing_labels(tmp_path: Path) -> None:
    src = tmp_path / "src"
    write_paper_llff(src, normals_folder="normal", label_folders=("label", "reshading"))
    (src / "label" / "003.png").unlink()
    summary = import_paper_llff(PaperLLFFImportConfig(src, tmp_path / "a"))
    frames = transforms(tmp_path / "a")["frames"]
    assert all("normals_file_path" in frame for frame in frames)  # normal/ accepted
    assert "semantics_file_path" not in frames[3] and all("semantics_file_path" in f for f in frames[:3])
    assert not any("edges_file_path" in frame or "keypoints_file_path" in frame for frame in frames)
    assert summary.label_counts == {"semantics": 9, "normals": 10, "shading": 10}
    assert "keypoint/" in summary.report() and "semantics (9/10 frames)" in summary.report()

    # both folders: normal_new/ wins, as the authors' loader reads it
    Image.fromarray(np.zeros((HEIGHT, WIDTH, 3), dtype=np.uint8)).save(src / "normal" / "000.png")
    (src / "normal_new").mkdir()
    Image.fromarray(np.full((HEIGHT, WIDTH, 3), 255, dtype=np.uint8)).save(src / "normal_new" / "000.png")
    import_paper_llff(PaperLLFFImportConfig(src, tmp_path / "b", normals_axes="RUB"))
    frames = transforms(tmp_path / "b")["frames"]
    assert [("normals_file_path" in frame) for frame in frames] == [True] + [False] * 9
    assert (read_png(tmp_path / "b" / frames[0]["normals_file_path"]) == 255).all()


def test_paper_llff_class_names(tmp_path: Path) -> None:
    src = tmp_path / "src"
    write_paper_llff(src, label_folders=("label",))
    names = tuple(f"c{i}" for i in range(12))
    with pytest.raises(DatasetInputError, match="--class-names") as error:
        import_paper_llff(PaperLLFFImportConfig(src, tmp_path / "dst", class_names=names[:5]))
    assert "label/000.png" in str(error.value) and "[11]" in str(error.value)
    assert not (tmp_path / "dst").exists()
    import_paper_llff(PaperLLFFImportConfig(src, tmp_path / "dst", class_names=names))
    meta = transforms(tmp_path / "dst")
    assert meta["semantic_classes"] == list(names) and "semantic_colors" not in meta


# --------------------------------------------------------------------------------------------------------------------
# semantic-nerf labels, splits, options


def test_semantic_nerf_splits_downscale_depth(replica) -> None:
    _, dst = replica
    meta = transforms(dst)
    assert meta["train_filenames"] == [f"images/frame_{i:05d}.png" for i in (0, 5, 10, 15)]
    assert meta["test_filenames"] == meta["val_filenames"] == [f"images/frame_{i:05d}.png" for i in (2, 7, 12, 17)]
    assert (meta["w"], meta["h"]) == (WIDTH, HEIGHT)
    assert meta["fl_x"] == meta["fl_y"] == pytest.approx(WIDTH / 2)  # 90 degree horizontal FoV
    assert (meta["cx"], meta["cy"]) == (WIDTH / 2, HEIGHT / 2)
    assert meta["ssnerf_import"]["downscale"] == 2
    for frame in meta["frames"]:
        number = int(frame["file_path"][-9:-4])
        assert read_png(dst / frame["file_path"]).shape == (HEIGHT, WIDTH, 3)
        depth = read_png(dst / frame["depth_file_path"])
        assert depth.dtype == np.uint16 and (depth == 1500 + number).all()
        assert "normals_file_path" not in frame
    semantics = read_png(dst / meta["frames"][0]["semantics_file_path"])
    assert semantics.shape == (HEIGHT, WIDTH)


def test_semantic_nerf_maps_replica_classes_by_name(tmp_path: Path) -> None:
    write_semantic_nerf(tmp_path / "src")
    summary = import_semantic_nerf(SemanticNeRFImportConfig(tmp_path / "src", tmp_path / "dst"))
    meta = transforms(tmp_path / "dst")
    assert meta["semantic_classes"] == list(SEMANTIC_CLASSES)
    assert meta["semantic_colors"] == [list(color) for color in SEMANTIC_COLORS]
    expected = {0: "void", 3: "wall", 7: "books", 40: "floor", 93: "sofa", 99: "objects"}
    lookup = np.zeros(100, dtype=np.uint8)
    for raw, name in expected.items():
        lookup[raw] = NYU[name]
    for frame in meta["frames"]:
        number = int(frame["file_path"][-9:-4])
        source = replica_semantics(2 * WIDTH, 2 * HEIGHT, number % 3)
        np.testing.assert_array_equal(read_png(tmp_path / "dst" / frame["semantics_file_path"]), lookup[source])
    report = summary.report()
    assert "zz-mystery" in report and "wall <- wall" in report and "bed" not in report.split("classes:")[1]
    assert REPLICA_CLASSES[99] == "zz-mystery"


def test_semantic_nerf_contiguous_ids_without_class_list(tmp_path: Path) -> None:
    write_semantic_nerf(tmp_path / "src", with_info=False)
    import_semantic_nerf(SemanticNeRFImportConfig(tmp_path / "src", tmp_path / "dst"))
    meta = transforms(tmp_path / "dst")
    assert meta["semantic_classes"] == ["void", "class_3", "class_7", "class_40", "class_93", "class_99"]
    assert "semantic_colors" not in meta
    lookup = np.zeros(100, dtype=np.uint8)
    lookup[[0, 3, 7, 40, 93, 99]] = np.arange(6)
    frame = meta["frames"][1]
    source = replica_semantics(2 * WIDTH, 2 * HEIGHT, 2 % 3)
    np.testing.assert_array_equal(read_png(tmp_path / "dst" / frame["semantics_file_path"]), lookup[source])


def test_cli_semantic_nerf_with_replica_info_option(tmp_path: Path, capsys) -> None:
    write_semantic_nerf(tmp_path / "src", with_info=False)
    info = tmp_path / "elsewhere.json"
    info.write_text(json.dumps({"classes": [{"id": key, "name": name} for key, name in REPLICA_CLASSES.items()]}))
    args = [
        "semantic-nerf",
        str(tmp_path / "src"),
        str(tmp_path / "dst"),
        "--replica-info",
        str(info),
        "--downscale",
        "2",
    ]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert out.startswith("ssnerf-import: wrote") and "train 4, val 4, test 4" in out and "ssnerf-label" in out
    assert transforms(tmp_path / "dst")["semantic_classes"] == list(SEMANTIC_CLASSES)


# --------------------------------------------------------------------------------------------------------------------
# bad input and the output folder


def _replace_with_garbage(path: Path) -> None:
    path.write_bytes(b"not a png")


def _resize(path: Path) -> None:
    Image.fromarray(np.zeros((7, 9, 3), dtype=np.uint8)).save(path)


LLFF_BREAKS: dict[str, tuple[Callable[[Path], None], str]] = {
    "src not a folder": (lambda src: None, "not a folder"),
    "no images/": (lambda src: shutil.rmtree(src / "images"), "images"),
    "no poses": (lambda src: (src / "poses_bounds.npy").unlink(), "poses_bounds.npy"),
    "pose count": (lambda src: (src / "images" / "009.png").unlink(), "poses_bounds.npy: 10 camera poses but 9"),
    "unreadable": (lambda src: _replace_with_garbage(src / "images" / "005.png"), "005.png"),
    "mixed sizes": (lambda src: _resize(src / "images" / "004.png"), "004.png"),
}
REPLICA_BREAKS: dict[str, tuple[Callable[[Path], None], str]] = {
    "src not a folder": (lambda src: None, "not a folder"),
    "no rgb/": (lambda src: (src / "rgb").rename(src / "colour"), "rgb"),
    "no trajectory": (lambda src: (src / "traj_w_c.txt").unlink(), "traj_w_c.txt"),
    "pose count": (lambda src: (src / "rgb" / "rgb_19.png").unlink(), "traj_w_c.txt: 20 camera poses but 19"),
    "unreadable": (lambda src: _replace_with_garbage(src / "rgb" / "rgb_7.png"), "rgb_7.png"),
    "mixed sizes": (lambda src: _resize(src / "rgb" / "rgb_5.png"), "rgb_5.png"),
    "missing depth": (lambda src: (src / "depth" / "depth_10.png").unlink(), "depth_10.png"),
}


@pytest.mark.parametrize(
    "layout, case",
    [("paper-llff", case) for case in LLFF_BREAKS] + [("semantic-nerf", case) for case in REPLICA_BREAKS],
)
def test_bad_input_errors_and_leaves_nothing(tmp_path: Path, layout: str, case: str) -> None:
    src, dst = tmp_path / "src", tmp_path / "out" / "nested" / "dst"
    if layout == "paper-llff":
        write_paper_llff(src, label_folders=())
        breaker, message = LLFF_BREAKS[case]
        config = PaperLLFFImportConfig(src, dst)
    else:
        write_semantic_nerf(src, num_frames=20, width=8, height=6)
        breaker, message = REPLICA_BREAKS[case]
        config = SemanticNeRFImportConfig(src, dst)
    if case == "src not a folder":
        config.src = src / "traj_w_c.txt" if layout == "semantic-nerf" else src / "poses_bounds.npy"
    breaker(src)
    with pytest.raises(DatasetInputError, match=message.replace(".", r"\.")):
        config.run()
    assert sorted(path.name for path in tmp_path.iterdir()) == ["src"]  # no dst, no parents, no temporary folder


def test_output_folder_rules(tmp_path: Path, capsys) -> None:
    src, dst = tmp_path / "src", tmp_path / "dst"
    write_paper_llff(src, label_folders=(), normals_folder="")
    dst.mkdir()
    (dst / "keep.txt").write_text("mine")
    assert main(["paper-llff", str(src), str(dst)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("ssnerf-import: ") and "--overwrite" in err and "Traceback" not in err
    assert [path.name for path in dst.iterdir()] == ["keep.txt"]

    # a failing --overwrite import keeps the old folder
    (src / "poses_bounds.npy").rename(src / "poses.bak")
    assert main(["paper-llff", str(src), str(dst), "--overwrite"]) == 1
    assert [path.name for path in dst.iterdir()] == ["keep.txt"]
    (src / "poses.bak").rename(src / "poses_bounds.npy")

    assert main(["paper-llff", str(src), str(dst), "--overwrite"]) == 0
    assert "properties: rgb" in capsys.readouterr().out
    assert sorted(path.name for path in dst.iterdir()) == ["images", "transforms.json"]
    assert sorted(path.name for path in tmp_path.iterdir()) == ["dst", "src"]

    with pytest.raises(DatasetInputError, match="holds the source"):
        import_paper_llff(PaperLLFFImportConfig(src, tmp_path, overwrite=True))


# --------------------------------------------------------------------------------------------------------------------
# training


@pytest.mark.parametrize("which", ["llff", "replica"])
def test_imported_datasets_train(which: str, request, tmp_path: Path) -> None:
    """The paper's release trains as imported; Semantic-NeRF's renders after `ssnerf-label` derived the rest."""
    _, imported = request.getfixturevalue(which)
    dst = tmp_path / "data"
    shutil.copytree(imported, dst)
    if which == "replica":
        report = label_dataset(LabelDatasetConfig(data=dst, workers=1), load_transforms(dst))
        assert all(report.labelled(spec.name) == 8 for spec in labelled_properties() if not spec.kind.categorical)
    properties = set(OPTIONAL_PROPERTIES)
    config = lite_config(dst, tmp_path / "outputs", iterations=3)
    config.steps_per_save = 10**6
    _, totals, dicts = train(config)
    assert len(totals) == 3 and all(np.isfinite(totals))
    for loss_dict in dicts:
        for name in ("rgb", *properties):
            assert np.isfinite(loss_dict[f"{name}_loss"]), name
