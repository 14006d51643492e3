"""Bad data never reaches training: each fault, made on a tiny generated dataset, stops `ns-train`, `ssnerf-label`
and `ssnerf-check` with one line naming the file (or frame) and the fix, no traceback, and every file unchanged."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Callable, Dict, List

import numpy as np
import pytest
from PIL import Image

from ssnerf_method.data.validate import MAX_LISTED, DatasetFaults, validate_dataset
from ssnerf_method.errors import UserError

from conftest import HEIGHT, WIDTH, snapshot, write_tiny_dataset

FRAME = "frame_003.png"


def edit(root: Path, change: Callable[[Dict], None]) -> None:
    meta = json.loads((root / "transforms.json").read_text())
    change(meta)
    (root / "transforms.json").write_text(json.dumps(meta))


def frame(meta: Dict, name: str = FRAME) -> Dict:
    return next(f for f in meta["frames"] if f["file_path"].endswith(name))


def replace_with_folder(path: Path) -> None:
    path.unlink()
    path.mkdir()


def set_pose(value: Callable[[List], object]) -> Callable[[Path], None]:
    def change(root: Path) -> None:
        edit(root, lambda meta: frame(meta).update(transform_matrix=value(frame(meta)["transform_matrix"])))
    return change


def nan_pose(matrix: List) -> List:
    matrix[0][3] = float("nan")
    return matrix


def bad_class(root: Path) -> None:
    ids = np.zeros((HEIGHT, WIDTH), dtype=np.uint8)
    ids[2, 3] = 200
    Image.fromarray(ids).save(root / "semantics" / FRAME)


FAULTS: Dict[str, tuple] = {
    # name: (make the fault in the dataset folder; --data to pass (None: the folder); words the line must hold)
    "nan pose": (set_pose(nan_pose), None, ["frames[", FRAME, "NaN", "pose"]),
    "3x4 pose": (set_pose(lambda m: m[:3]), None, ["frames[", FRAME, "3x4", "[0, 0, 0, 1]"]),
    "truncated transforms.json": (lambda root: (root / "transforms.json").write_text(
        (root / "transforms.json").read_text()[:300]), None, ["transforms.json", "not valid JSON", "Restore"]),
    "missing image": (lambda root: (root / "images" / FRAME).unlink(), None, [f"images/{FRAME}", "does not exist"]),
    "garbage image": (lambda root: (root / "images" / FRAME).write_bytes(b"\x89PNG\r\n\x1a\nnot a png at all"), None,
                      [f"images/{FRAME}", "cannot be decoded", "Re-export"]),
    "images of mixed sizes": (lambda root: Image.new("RGB", (20, 10)).save(root / "images" / FRAME), None,
                              [f"images/{FRAME}", "20x10", f"{WIDTH}x{HEIGHT}"]),
    "unknown camera model": (lambda root: edit(root, lambda meta: meta.update(camera_model="KANNALA_BRANDT")), None,
                             ["transforms.json", "KANNALA_BRANDT", "not one nerfstudio supports", "OPENCV"]),
    "FISHEYE624 without its parameters": (lambda root: edit(root, lambda meta: meta.update(camera_model="FISHEYE624")),
                                          None, ["transforms.json", "FISHEYE624", "distortion_params", "12 numbers"]),
    "8-bit RGB depth": (lambda root: Image.new("RGB", (WIDTH, HEIGHT), (9, 9, 9)).save(root / "depth" / FRAME), None,
                        [f"depth/{FRAME}", "16-bit", "depth_file_path"]),
    "empty depth file": (lambda root: (root / "depth" / FRAME).write_bytes(b""), None,
                         [f"depth/{FRAME}", "cannot be decoded"]),
    "depth path is a folder": (lambda root: replace_with_folder(root / "depth" / FRAME), None,
                               [f"depth/{FRAME}", "is a folder"]),
    "depth zero everywhere": (lambda root: Image.fromarray(np.zeros((HEIGHT, WIDTH), np.uint16)).save(
        root / "depth" / FRAME), None, [f"depth/{FRAME}", "zero", "everywhere"]),
    "all-zero normals": (lambda root: Image.new("RGB", (WIDTH, HEIGHT)).save(root / "normals" / FRAME), None,
                         [f"normals/{FRAME}", "not unit normals", "(n + 1) / 2"]),
    "label of the wrong size": (lambda root: Image.new("L", (WIDTH + 2, HEIGHT - 4)).save(root / "shading" / FRAME),
                                None, [f"shading/{FRAME}", f"{WIDTH}x{HEIGHT}", "Resize"]),
    "class id outside semantic_classes": (bad_class, None, [f"semantics/{FRAME}", "200", "semantic_classes"]),
    "label path is a folder": (lambda root: replace_with_folder(root / "edges" / FRAME), None,
                               [f"edges/{FRAME}", "is a folder"]),
    "missing label": (lambda root: (root / "keypoints" / FRAME).unlink(), None,
                      [f"keypoints/{FRAME}", "does not exist"]),
    "no transforms.json": (lambda root: (root / "transforms.json").unlink(), None, ["transforms.json", "missing"]),
    "wrong folder": (lambda root: None, "nope", ["nope"]),
}


@pytest.fixture(params=list(FAULTS))
def faulty(request, tmp_path: Path):
    """(fault name, --data path, expected words, dataset folder, its snapshot) for one fault."""
    root = tmp_path / "data"
    write_tiny_dataset(root, num_frames=6)
    make, data, words = FAULTS[request.param]
    make(root)
    return request.param, (root / data if data else root), words, root, snapshot(root)


def fault_lines(stderr: str, program: str) -> List[str]:
    assert "Traceback" not in stderr, stderr
    return [line for line in stderr.splitlines() if line.startswith(f"{program}: ")]


def assert_one_line(lines: List[str], words: List[str]) -> None:
    assert len(lines) == 1, lines
    assert all(word in lines[0] for word in words), (lines[0], words)


def test_ssnerf_check(faulty, capsys) -> None:
    from ssnerf_method.cli.check import CheckConfig, main

    _, data, words, root, before = faulty
    assert main(CheckConfig(data=data)) == 1
    assert_one_line(fault_lines(capsys.readouterr().err, "ssnerf-check"), words)
    assert snapshot(root) == before


def test_ssnerf_label(faulty, capsys, monkeypatch) -> None:
    from ssnerf_method.cli import label

    _, data, words, root, before = faulty
    monkeypatch.setattr(sys, "argv", ["ssnerf-label", str(data), "--workers", "1"])
    with pytest.raises(SystemExit) as exit_info:
        label.entrypoint()
    assert exit_info.value.code == 1
    assert_one_line(fault_lines(capsys.readouterr().err, "ssnerf-label"), words)
    assert snapshot(root) == before


def test_ns_train(faulty, capsys, monkeypatch, tmp_path: Path) -> None:
    """nerfstudio's own `ns-train` entrypoint, in this process: the error it raises is what the interpreter hands to
    `sys.excepthook` (which importing the plugin set) when the command is run."""
    from nerfstudio.scripts.train import entrypoint

    _, data, words, root, before = faulty
    monkeypatch.setattr(sys, "argv", ["ns-train", "ssnerf-lite", "--data", str(data), "--vis", "tensorboard",
                                      "--output-dir", str(tmp_path / "outputs"), "--max-num-iterations", "2",
                                      "--machine.device-type", "cpu"])
    with pytest.raises(UserError) as error:
        entrypoint()
    capsys.readouterr()
    sys.excepthook(type(error.value), error.value, error.value.__traceback__)
    assert_one_line(fault_lines(capsys.readouterr().err, "ns-train"), words)
    assert snapshot(root) == before


def test_ns_train_process_reports_one_line(tmp_path: Path) -> None:
    """The real command: exit status 1, the fault on stderr, no traceback, the NaN pose caught before training."""
    root = tmp_path / "data"
    write_tiny_dataset(root, num_frames=6)
    set_pose(nan_pose)(root)
    before = snapshot(root)
    result = subprocess.run(
        [Path(sys.executable).with_name("ns-train"), "ssnerf-lite", "--data", str(root), "--vis", "tensorboard",
         "--output-dir", str(tmp_path / "outputs"), "--max-num-iterations", "2", "--machine.device-type", "cpu"],
        capture_output=True, text=True, timeout=300,
    )
    assert result.returncode == 1
    assert_one_line(fault_lines(result.stderr, "ns-train"), ["frames[", FRAME, "NaN"])
    assert snapshot(root) == before


def test_every_fault_is_listed_in_one_pass(tiny_dataset: Path) -> None:
    """Several faults at once: one line each, in one pass; past `MAX_LISTED` the error points at `ssnerf-check`."""
    for make in ("nan pose", "all-zero normals", "class id outside semantic_classes", "missing label"):
        FAULTS[make][0](tiny_dataset)
    validation = validate_dataset(tiny_dataset)
    assert len(validation.faults) == 4
    for name in (FRAME, f"normals/{FRAME}", f"semantics/{FRAME}", f"keypoints/{FRAME}"):
        assert sum(name in fault for fault in validation.faults) >= 1
    many = DatasetFaults([f"fault {index}" for index in range(MAX_LISTED + 5)], tiny_dataset)
    lines = str(many).splitlines()
    assert len(lines) == MAX_LISTED + 1 and "5 more" in lines[-1] and f"ssnerf-check {tiny_dataset}" in lines[-1]


def test_clean_dataset_passes(tiny_dataset: Path, capsys) -> None:
    from ssnerf_method.cli.check import CheckConfig, main

    validation = validate_dataset(tiny_dataset)
    assert validation.ok and validation.num_frames == 6 and validation.labelled["normals"] == 6
    assert main(CheckConfig(data=tiny_dataset)) == 0
    assert "OK, 6 frames" in capsys.readouterr().out


def test_headers_only_skips_pixel_checks(tiny_dataset: Path) -> None:
    """`contents=False` reads no pixels: a header fault is still found, a pixel fault is not."""
    FAULTS["all-zero normals"][0](tiny_dataset)
    assert validate_dataset(tiny_dataset, contents=False).ok
    assert not validate_dataset(tiny_dataset).ok
    FAULTS["label of the wrong size"][0](tiny_dataset)
    assert len(validate_dataset(tiny_dataset, contents=False).faults) == 1


# Training guards: a broken model stops with one line instead of saving NaN checkpoints or writing NaN metrics.


def test_non_finite_loss_stops_training_at_that_step(tmp_path: Path, monkeypatch) -> None:
    from ssnerf_method.model.ssnerf_model import SSNeRFModel
    from ssnerf_method.pipelines.ssnerf_pipeline import TrainingDiverged

    from test_training import lite_config, train

    original = SSNeRFModel.get_loss_dict
    calls = []

    def poisoned(self, outputs, batch, metrics_dict=None):
        losses = original(self, outputs, batch, metrics_dict)
        calls.append(1)
        if len(calls) == 4:  # the fourth training step
            losses["shading_loss"] = losses["shading_loss"] * float("nan")
        return losses

    monkeypatch.setattr(SSNeRFModel, "get_loss_dict", poisoned)
    write_tiny_dataset(tmp_path / "data")
    config = lite_config(tmp_path / "data", tmp_path / "outputs", 8)
    config.steps_per_save = 2
    with pytest.raises(TrainingDiverged, match=r"^step 3: loss shading_loss is not finite") as error:
        train(config)
    assert len(str(error.value).splitlines()) == 1
    saved = sorted(path.name for path in config.get_checkpoint_dir().glob("step-*.ckpt"))
    assert saved and saved[-1] <= "step-000000002.ckpt"  # nothing from the step that went NaN or later


def test_ns_eval_on_a_nan_model_fails_clearly(trained_scene, tmp_path: Path, monkeypatch, capsys) -> None:
    from nerfstudio.scripts.eval import ComputePSNR

    from ssnerf_method.model.ssnerf_model import SSNeRFModel
    from ssnerf_method.pipelines.ssnerf_pipeline import TrainingDiverged

    _, config_path = trained_scene
    original = SSNeRFModel.render_camera

    def nan_render(self, *args, **kwargs):
        outputs = original(self, *args, **kwargs)
        outputs["rgb"] = outputs["rgb"] * float("nan")
        return outputs

    monkeypatch.setattr(SSNeRFModel, "render_camera", nan_render)
    output = tmp_path / "eval.json"
    with pytest.raises(TrainingDiverged, match="renders NaN or infinite colours") as error:
        ComputePSNR(load_config=config_path, output_path=output).main()
    assert not output.exists()
    capsys.readouterr()
    sys.excepthook(type(error.value), error.value, error.value.__traceback__)
    assert len(fault_lines(capsys.readouterr().err, Path(sys.argv[0]).name)) == 1


def test_ns_eval_on_an_empty_checkpoint_folder(trained_scene, tmp_path: Path) -> None:
    import yaml

    from nerfstudio.scripts.eval import ComputePSNR

    _, config_path = trained_scene
    config = yaml.load(config_path.read_text(), Loader=yaml.Loader)
    config.output_dir, config.timestamp = tmp_path / "outputs", "empty"
    config.get_checkpoint_dir().mkdir(parents=True)
    copied = tmp_path / "config.yml"
    copied.write_text(yaml.dump(config), "utf8")
    with pytest.raises(UserError, match="nerfstudio_models: holds no checkpoint"):
        ComputePSNR(load_config=copied, output_path=tmp_path / "eval.json").main()


def test_the_docs_list_exactly_these_faults() -> None:
    readme = (Path(__file__).parents[1] / "docs" / "dataset-format.md").read_text()
    block = readme.split("<!-- bad-input list: tests/test_validation.py FAULTS -->")[1].split("<!-- end of")[0]
    listed = [line[2:].split(":")[0] for line in block.strip().splitlines()]
    assert listed == list(FAULTS)


def test_traceback_on_request(tiny_dataset: Path, capsys, monkeypatch) -> None:
    """`SSNERF_TRACEBACK=1` hands the error to Python's own hook: the full traceback, for debugging."""
    FAULTS["nan pose"][0](tiny_dataset)
    with pytest.raises(UserError) as error:
        validate_dataset(tiny_dataset).raise_if_faulty()
    monkeypatch.setenv("SSNERF_TRACEBACK", "1")
    monkeypatch.setattr(sys, "argv", ["ns-train"])
    sys.excepthook(type(error.value), error.value, error.value.__traceback__)
    assert "Traceback (most recent call last)" in capsys.readouterr().err
