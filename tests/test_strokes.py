"""Strokes painted in the viewer: the strokes file, its rays in a run's frame, the Label panel's painting, sparse
labels given their share of each batch, and a stroke teaching the surface it covers to a view that never saw it."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Dict

import numpy as np
import pytest
import torch
from PIL import Image
from scipy.ndimage import binary_erosion

from nerfstudio.cameras.cameras import Cameras
from nerfstudio.data.pixel_samplers import PixelSampler, PixelSamplerConfig
from nerfstudio.utils.eval_utils import eval_setup

from ssnerf_method.data.datamanager import append_labels
from ssnerf_method.data.io import DatasetInputError
from ssnerf_method.data.pixel_sampler import LabelledPixelSamplerConfig
from ssnerf_method.data.strokes import STROKES_FILE, Stroke, StrokeStore, WorldFrame
from ssnerf_method.evaluation.heuristic import PinholeView, splat
from ssnerf_method.label_makers.encoding import SEMANTIC_IGNORE
from ssnerf_method.scene.make_scene import MakeSceneConfig, make_scene
from ssnerf_method.viewer.label_panel import MAX_RAYS_PER_STROKE, LabelPanel, box_pixels, disc_pixels

from test_viewer_browser import HEIGHT, NUM_FRAMES, TRAIN_STEPS, WIDTH, tiny_lite_config

FRAME = WorldFrame(np.array([[0.0, -1.0, 0.0, 0.3], [1.0, 0.0, 0.0, -0.2], [0.0, 0.0, 1.0, 0.1]]), 0.5)
"""A run frame that rotates, moves and scales the dataset's (as nerfstudio's orientation and scaling do)."""


def camera(c2w: np.ndarray, width: int = 20, height: int = 16) -> Cameras:
    return Cameras(camera_to_worlds=torch.from_numpy(c2w[None, :3]).float(), fx=15.0, fy=15.0, cx=width / 2,
                   cy=height / 2, width=width, height=height)


def a_stroke(class_name: str = "wall", rays: int = 3) -> Stroke:
    rng = np.random.default_rng(rays)
    directions = rng.normal(size=(rays, 3))
    return Stroke(class_name, rng.normal(size=(rays, 3)), directions / np.linalg.norm(directions, axis=-1,
                                                                                         keepdims=True),
                  np.eye(4)[:3], 1e-4)


def test_stroke_store_writes_every_change_and_reads_it_back(tmp_path: Path) -> None:
    path = tmp_path / STROKES_FILE
    store = StrokeStore.load(path)
    assert not path.exists() and store.strokes == []
    first, second = a_stroke("wall"), a_stroke("rug", rays=5)
    store.add(first)
    store.add_class("rug")
    store.add(second)
    reread = StrokeStore.load(path)
    assert [stroke.class_name for stroke in reread.strokes] == ["wall", "rug"] and reread.classes == ["rug"]
    np.testing.assert_allclose(reread.strokes[1].directions, second.directions, atol=1e-6)
    np.testing.assert_allclose(reread.strokes[0].origins, first.origins, atol=1e-6)
    assert reread.num_rays() == 8
    version = store.version
    assert store.undo() is not None and store.version > version
    assert [stroke.class_name for stroke in StrokeStore.load(path).strokes] == ["wall"]
    assert not list(path.parent.glob(".*")), "a temporary file was left beside the strokes file"


@pytest.mark.parametrize("content, fault", [
    ("{not json", "cannot be read"),
    (json.dumps({"strokes": []}), "not a strokes file"),
    (json.dumps({"format": "ssnerf-strokes", "strokes": [{"class": "wall"}]}), "stroke 0"),
    (json.dumps({"format": "ssnerf-strokes", "strokes": [{"class": "wall", "camera_to_world": np.eye(4)[:3].tolist(),
                                                          "pixel_area": 1e-4, "origins": [[0, 0, 0]],
                                                          "directions": [[0, 0, 1], [0, 1, 0]]}]}), "same"),
    (json.dumps({"format": "ssnerf-strokes", "strokes": [{"class": "wall", "camera_to_world": np.eye(4).tolist(),
                                                          "pixel_area": 1e-4, "origins": [[0, 0, 0]],
                                                          "directions": [[0, 0, 1]]}]}), "3x4"),
])
def test_a_strokes_file_that_does_not_parse_is_one_line_naming_it(tmp_path: Path, content: str, fault: str) -> None:
    path = tmp_path / STROKES_FILE
    path.parent.mkdir(parents=True)
    path.write_text(content)
    with pytest.raises(DatasetInputError) as error:
        StrokeStore.load(path)
    message = str(error.value)
    assert "\n" not in message and message.startswith(str(path)) and fault in message and "delete" in message
    assert path.read_text() == content


def test_stroke_rays_are_the_painting_cameras_rays_in_the_runs_frame() -> None:
    c2w = np.eye(4)
    c2w[:3, :3] = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    c2w[:3, 3] = [0.2, -0.5, 0.3]
    painted_from = camera(c2w)  # in the run's frame, as the viewer gives it
    panel = LabelPanel(StrokeStore(Path("unused.json")), FRAME, ["void", "wall"], 4, torch.rand(4, 3), 16, True)
    panel.store._write = lambda strokes, classes: None  # (no file here)
    panel.b_class.value = panel.entries()[1]
    stroke = panel.paint_disc(painted_from, (0.25, 0.5), 2.0)
    assert stroke is not None and stroke.class_name == "wall"
    pixels = disc_pixels((5.0, 8.0), 2.0, 20, 16)
    assert len(stroke.origins) == len(pixels) == 12
    # stored in the dataset's frame: back in the run's frame they are the camera's own rays at those pixels
    expected = painted_from.generate_rays(0, coords=torch.from_numpy(pixels[:, ::-1] + 0.5).float())
    rays = panel.store.labelled_rays(FRAME, {"void": 0, "wall": 1})
    assert rays is not None
    np.testing.assert_allclose(rays.origins.numpy(), expected.origins.numpy(), atol=1e-5)
    np.testing.assert_allclose(rays.directions.numpy(), expected.directions.numpy(), atol=1e-5)
    np.testing.assert_allclose(rays.directions_norm.numpy(), expected.metadata["directions_norm"].numpy(), atol=1e-4)
    np.testing.assert_allclose(rays.camera_to_world.numpy()[0], c2w[:3].reshape(12), atol=1e-5)
    assert (rays.class_ids == 1).all()
    assert not np.allclose(stroke.origins, expected.origins.numpy()), "the file must hold the dataset's frame"
    assert panel.store.labelled_rays(FRAME, {"void": 0}) is None, "a stroke of an unknown class is left out"


def test_brush_and_box_pixels() -> None:
    assert disc_pixels((3.5, 2.5), 0.4, 8, 6).tolist() == [[3, 2]]
    assert disc_pixels((-5.0, -5.0), 1.0, 8, 6).tolist() == [[0, 0]], "a click outside still paints its edge pixel"
    box = box_pixels((0.25, 0.5), (0.5, 1.0), 8, 6)
    assert sorted(map(tuple, box)) == [(x, y) for x in (2, 3) for y in (3, 4, 5)]
    big = box_pixels((0.0, 0.0), (1.0, 1.0), 400, 300)
    assert 0 < len(big) <= MAX_RAYS_PER_STROKE and big[:, 0].max() > 390


def test_adding_a_class_takes_a_free_slot_and_is_recorded(tmp_path: Path) -> None:
    store = StrokeStore.load(tmp_path / STROKES_FILE)
    told = []
    panel = LabelPanel(store, FRAME, ["void", "wall"], 3, torch.rand(3, 3), 16, False, on_new_class=told.append)
    assert panel.paint_disc(camera(np.eye(4)), (0.5, 0.5), 1.0) is not None  # "void" picked first
    assert panel.add_class("rug") and panel.class_id == 2 and told == [["void", "wall", "rug"]]
    assert StrokeStore.load(store.path).classes == ["rug"]
    assert not panel.add_class("lamp") and "No free class slot" in panel.h_status.value
    assert panel.add_class("wall") and panel.class_id == 1, "an existing name is picked, not added"
    assert "next ns-train" in panel.summary()


def image_batch(labelled_pixels: int) -> Dict[str, torch.Tensor]:
    """Three 10x12 images whose colour is the pixel's own (image in batch, row, column), and semantics labelled
    (class 2) at `labelled_pixels` random pixels."""
    grid = torch.stack(torch.meshgrid(torch.arange(3), torch.arange(10), torch.arange(12), indexing="ij"), -1)
    semantics = torch.full((3, 10, 12, 1), float(SEMANTIC_IGNORE))
    flat = semantics.view(-1)
    flat[torch.randperm(flat.numel(), generator=torch.Generator().manual_seed(0))[:labelled_pixels]] = 2.0
    return {"image": grid.float(), "semantics": semantics, "image_idx": torch.tensor([4, 5, 6])}


def test_sparse_labels_get_their_share_of_each_batch() -> None:
    sampler = LabelledPixelSamplerConfig(num_rays_per_batch=64, labelled_rays_per_batch=16).setup()
    batch = sampler.sample(image_batch(labelled_pixels=5))
    labelled = batch["semantics"][:, 0] != SEMANTIC_IGNORE
    assert batch["image"].shape == (64, 3) and batch["indices"].shape == (64, 3)
    assert labelled[-16:].all() and labelled.sum() >= 16
    # every row is one whole pixel: its camera index is its image's, its colour (= its place) and label agree
    assert torch.equal(batch["indices"][:, 0], batch["image"][:, 0].long() + 4)
    assert torch.equal(batch["indices"][:, 1:], batch["image"][:, 1:].long())

    dense = {**image_batch(0), "semantics": torch.zeros(3, 10, 12, 1)}
    torch.manual_seed(3)
    ours = LabelledPixelSamplerConfig(num_rays_per_batch=64).setup().sample(dense)
    torch.manual_seed(3)
    plain = PixelSampler(PixelSamplerConfig(num_rays_per_batch=64)).sample(dense)
    assert all(torch.equal(ours[key], plain[key]) for key in plain), "dense labels are sampled as nerfstudio does"


def test_stroke_rows_carry_their_class_and_nothing_else() -> None:
    batch = {"image": torch.rand(4, 3), "semantics": torch.ones(4, 1), "normals": torch.rand(4, 3),
             "shading": torch.rand(4, 1), "depth_metres": torch.rand(4, 1), "indices": torch.zeros(4, 3).long()}
    extended = append_labels(batch, torch.tensor([[7.0], [2.0]]))
    assert extended["semantics"][4:, 0].tolist() == [7.0, 2.0]
    assert torch.isnan(extended["image"][4:]).all() and torch.isnan(extended["normals"][4:]).all()
    assert torch.isnan(extended["shading"][4:]).all() and (extended["depth_metres"][4:] == 0).all()
    assert extended["indices"].shape == (6, 3) and torch.equal(extended["image"][:4], batch["image"])


@pytest.fixture(scope="module")
def stroked_run(tmp_path_factory):
    """The viewer test's generated 64x48 scene, whose frames have no semantic label file (its classes declared);
    from training view 0, the pixels of its two largest classes are painted in their class and those of the third as
    a class added in the panel ("rug"); then the viewer test's small `ssnerf-lite` trains for 300 steps on one thread
    (~30 s)."""
    torch.set_num_threads(1)
    torch.manual_seed(0)
    root = tmp_path_factory.mktemp("stroked")
    scene = root / "scene"
    make_scene(MakeSceneConfig(output_dir=scene, width=WIDTH, height=HEIGHT, num_frames=NUM_FRAMES, seed=0))
    meta = json.loads((scene / "transforms.json").read_text())
    for frame in meta["frames"]:
        del frame["semantics_file_path"]
    (scene / "transforms.json").write_text(json.dumps(meta))
    config = tiny_lite_config(scene, root / "outputs")
    trainer = config.setup(local_rank=0, world_size=1)
    trainer.setup()
    pipeline = trainer.pipeline
    panel: LabelPanel = pipeline.model.semantic_labelling
    cameras = pipeline.datamanager.train_dataset.cameras
    names = [Path(name).name for name in pipeline.datamanager.train_dataset.image_filenames]
    truth = np.asarray(Image.open(scene / "semantics" / names[0]))
    ids, counts = np.unique(truth, return_counts=True)
    largest = [int(i) for i in ids[np.argsort(-counts)][:3]]
    painted = np.full(truth.shape, -1)
    for rank, class_id in enumerate(largest):
        if rank < 2:
            panel.b_class.value = panel.entries()[class_id]
        else:
            assert panel.add_class("rug")
        rows, columns = np.nonzero(truth == class_id)
        assert panel.paint(cameras[0], np.stack([columns, rows], axis=-1)) is not None
        painted[truth == class_id] = panel.class_id
    config.save_config()
    trainer.train()
    return scene, config.get_base_dir() / "config.yml", pipeline, painted


def test_a_stroke_teaches_the_surface_it_covers_to_other_views(stroked_run) -> None:
    """In the training view that sees most of the painted surface (found by warping view 0's painted pixels with
    its depth map, as the Heuristic does), that surface renders in the painted classes. Only pixels a pixel away from
    a painted region's edge are scored: warping moves edges by a pixel or so."""
    scene, _, pipeline, painted = stroked_run
    interior = np.full_like(painted, -1)
    for class_id in np.unique(painted[painted >= 0]):
        inside = binary_erosion(painted == class_id)
        interior[inside] = class_id
    model = pipeline.model.eval()
    train = pipeline.datamanager.train_dataset
    scale = train.metadata["dataparser_scale"]
    source = PinholeView.from_cameras(train.cameras, 0)
    depth = train[0]["depth_metres"][..., 0].numpy().astype(np.float64) * scale
    best = None
    for view in range(1, len(train)):  # the other view that sees most of the painted surface
        hit, pixel, _ = splat(source, depth, PinholeView.from_cameras(train.cameras, view))
        expected = interior.reshape(-1)[pixel]
        if best is None or (expected >= 0).sum() > (best[2] >= 0).sum():
            best = (view, hit, expected)
    view, hit, expected = best
    seen = expected >= 0
    assert seen.sum() > 200, "the painted surface must be in sight of another training view"
    with torch.no_grad():
        outputs = model.render_camera(train.cameras[view : view + 1])
    predicted = outputs["semantics_logits"].argmax(-1).reshape(-1).numpy()[hit[seen]]
    accuracy = float((predicted == expected[seen]).mean())
    rug = int(expected.max())
    assert rug == len(json.loads((scene / "transforms.json").read_text())["semantic_classes"]), "rug: a spare slot"
    rug_accuracy = float((predicted[expected[seen] == rug] == rug).mean())
    # measured 0.80-0.94 and 0.48-0.61 (the painting, painted as rug, is partly taken for the similarly coloured bed
    # after 300 steps); a stroke that trained nothing scores near 0
    assert accuracy > 0.7 and rug_accuracy > 0.35, (accuracy, rug_accuracy)


def test_a_model_trained_with_strokes_loads_like_any_other(stroked_run) -> None:
    scene, config_path, pipeline, _ = stroked_run
    _, loaded, _, step = eval_setup(config_path, test_mode="test")
    assert step == TRAIN_STEPS - 1
    assert loaded.model.class_names[-1] == "rug" and loaded.model.num_classes == pipeline.model.num_classes
    assert not loaded.model.semantic_labelling.training_run, "ns-viewer's panel saves strokes for the next run"
    camera_outputs = loaded.model.get_outputs_for_camera(loaded.datamanager.eval_dataset.cameras[0:1])
    assert camera_outputs["semantics"].shape[-1] == 3


def test_ssnerf_check_and_ns_train_stop_at_a_strokes_file_that_does_not_parse(tiny_dataset: Path) -> None:
    path = tiny_dataset / STROKES_FILE
    path.parent.mkdir(parents=True)
    path.write_text('{"format": "ssnerf-strokes", "strokes": [{"class": "wall"}')
    before = {file: file.read_bytes() for file in tiny_dataset.rglob("*") if file.is_file()}
    for command in (["ssnerf-check", str(tiny_dataset)],
                    ["ns-train", "ssnerf-lite", "--data", str(tiny_dataset), "--max-num-iterations", "1",
                     "--vis", "tensorboard", "--output-dir", str(tiny_dataset.parent / "outputs")]):
        result = subprocess.run([str(Path(sys.executable).parent / command[0]), *command[1:]], capture_output=True,
                                text=True, timeout=300, env={**os.environ, "OMP_NUM_THREADS": "1"})
        assert result.returncode == 1, result.stderr[-2000:]
        faults = [line for line in result.stderr.splitlines() if str(path) in line]
        assert len(faults) == 1 and "Traceback" not in result.stderr, result.stderr[-2000:]
    assert before == {file: file.read_bytes() for file in tiny_dataset.rglob("*") if file.is_file()}


def test_a_stroke_that_cannot_be_saved_is_said_in_the_panel(tmp_path: Path, monkeypatch) -> None:
    store = StrokeStore.load(tmp_path / STROKES_FILE)
    panel = LabelPanel(store, FRAME, ["void", "wall"], 2, torch.rand(2, 3), 16, True)
    assert panel.paint_disc(camera(np.eye(4)), (0.5, 0.5), 1.0) is not None

    def read_only(path, mode="w"):
        raise PermissionError(13, "Permission denied", str(path))

    monkeypatch.setattr("ssnerf_method.data.strokes.atomic_file", read_only)
    version = store.version
    assert panel.paint_disc(camera(np.eye(4)), (0.5, 0.5), 1.0) is None
    assert "cannot be written (Permission denied)" in panel.h_status.value
    assert len(store.strokes) == 1 and store.version == version, "the store holds only what the file holds"
    assert len(StrokeStore.load(store.path).strokes) == 1


@pytest.mark.parametrize("message, reason", [
    ({"disc": ((1.5, 0.5), 3.0)}, "outside the image"),
    ({"disc": ((0.5, float("nan")), 3.0)}, "outside the image"),
    ({"disc": ((0.5, 0.5), 500.0)}, "brush radius 500"),
    ({"disc": ((0.5, 0.5), 0.0)}, "brush radius 0"),
    ({"box": ((0.1, 0.1), (0.5, 2.0))}, "outside the image"),
    ({"box": ((0.1,), (0.5, 0.5))}, "outside the image"),
    ({"class": "9: sofa", "disc": ((0.5, 0.5), 3.0)}, "class '9: sofa' is not in the list"),
    ({"new_class": "x" * 65}, "at most 64 printable characters"),
    ({"new_class": "bad\nname"}, "at most 64 printable characters"),
])
def test_a_clients_stroke_is_checked_before_anything_is_written(tmp_path: Path, message, reason) -> None:
    """Messages a browser (or anything reaching the port) sends: a class not in the list, a position outside the
    image, a brush outside the slider's range, an unbounded class name: refused, said in the panel, nothing written."""
    store = StrokeStore.load(tmp_path / STROKES_FILE)
    panel = LabelPanel(store, FRAME, ["void", "wall"], 4, torch.rand(4, 3), 16, True)
    assert panel.paint_disc(camera(np.eye(4)), (0.5, 0.5), 3.0) is not None  # a good stroke is saved
    before = store.path.read_bytes()
    if "class" in message:
        panel.b_class.value = message["class"]
    if "disc" in message:
        assert panel.paint_disc(camera(np.eye(4)), *message["disc"]) is None
    if "box" in message:
        assert panel.paint_box(camera(np.eye(4)), *message["box"]) is None
    if "new_class" in message:
        assert not panel.add_class(message["new_class"])
    assert reason in panel.h_status.value
    assert store.path.read_bytes() == before and len(store.strokes) == 1 and panel.class_names == ["void", "wall"]


def test_suggested_clicks_are_asked_answered_as_strokes_and_skipped(tiny_dataset: Path) -> None:
    """The Label panel's questions without a browser: the guess is picked, an answer is a one-ray stroke through the
    click's pixel from its frame's camera plus the class in the suggestion file, a skip is marked, a bad class from a
    client writes nothing, and the end is said."""
    store = StrokeStore.of_dataset(tiny_dataset)
    panel = LabelPanel(store, FRAME, ["void", "wall", "floor", "table"], 4, torch.rand(4, 3), 12, False)
    assert panel.ask() is None and "no suggested clicks yet" in panel.h_status.value
    meta = json.loads((tiny_dataset / "transforms.json").read_text())
    frames = [frame["file_path"] for frame in meta["frames"]]
    path = tiny_dataset / "ssnerf_labels" / "suggested_clicks.json"
    path.parent.mkdir(exist_ok=True)
    path.write_text(json.dumps({"clicks": [
        {"file_path": frames[1], "x": 3, "y": 4, "class": None, "guess": "table", "uncertainty": 0.9, "point": None},
        {"file_path": frames[2], "x": 5, "y": 6, "class": None, "guess": "wall", "uncertainty": 0.8, "point": None},
        {"file_path": frames[3], "x": 15, "y": 11, "class": None, "guess": "floor", "uncertainty": 0.7,
         "point": [0.0, 0.0, 0.0]}]}))

    question = panel.ask()
    assert question is not None and question.index == 0 and panel.b_class.value == "3: table"
    assert "Click 1 of 3" in panel.h_status.value and "guesses 'table'" in panel.h_status.value
    panel.b_class.value = "7: dragon"  # a client's value that is not in the list
    assert panel.answer() is None and "not in the list" in panel.h_status.value and not store.path.exists()
    panel.b_class.value = "2: floor"
    stroke = panel.answer()
    assert stroke is not None and stroke.class_name == "floor" and len(stroke.origins) == 1
    pose = np.asarray(meta["frames"][1]["transform_matrix"])[:3]
    through = pose[:, :3] @ np.array([(3.5 - meta["cx"]) / meta["fl_x"], -(4.5 - meta["cy"]) / meta["fl_y"], -1.0])
    assert stroke.origins[0] == pytest.approx(pose[:, 3]) and stroke.directions[0] == pytest.approx(
        through / np.linalg.norm(through))
    assert [s.class_name for s in StrokeStore.of_dataset(tiny_dataset).strokes] == ["floor"]  # saved at once
    assert json.loads(path.read_text())["clicks"][0]["class"] == "floor"
    assert panel.question is not None and panel.question.index == 1 and "Click 2 of 3" in panel.h_status.value

    panel.skip()
    assert json.loads(path.read_text())["clicks"][1]["skipped"] is True and panel.question.index == 2
    assert panel.answer() is not None and panel.question is None
    assert "No suggested click left (2 answered, 1 skipped)" in panel.h_status.value
    assert [s.class_name for s in StrokeStore.of_dataset(tiny_dataset).strokes] == ["floor", "floor"]
