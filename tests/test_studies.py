"""`ssnerf-study` end to end with --quick: each study writes its table with the paper's rows and columns, the runs
carry their overrides into the trained model, runs are shared between studies by name, and a second call retrains
nothing."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any, Dict

import numpy as np
import pytest
import torch
from PIL import Image

from nerfstudio.utils.eval_utils import eval_setup

from ssnerf_method.experiments import benchmark, sparsity
from ssnerf_method.experiments.augmentation import SETTINGS, AugmentationStudy
from ssnerf_method.experiments.autolabel import AutoLabelStudy
from ssnerf_method.experiments.propagation import (
    ALL_FRAMES,
    BOUND,
    CEILING,
    CLASS_IOU,
    DRAW,
    DRAWS,
    HEURISTIC,
    HIGHEST,
    LOWEST,
    NEAREST_POINT,
    ON_SEEN,
    ON_TRAIN,
    ON_UNSEEN,
    SEEN,
    SSNERF,
    PropagationStudy,
    dense_bound,
    over_draws,
    seen_pixels,
)
from ssnerf_method.experiments.report import BASELINE_ROWS
from ssnerf_method.experiments.sparsity import SparsityStudy
from ssnerf_method.experiments.studies import (
    BranchStudy,
    ClassGridStudy,
    MultiTaskStudy,
    RGBStudy,
    run_study,
    together,
)
from ssnerf_method.experiments.transfer import TransferStudy


def assert_planned(study, output: Path, since: float) -> None:
    """What `--launcher ray` would have run before the report is exactly what the local run trained: every planned
    job's result exists, and every model trained since `since` was planned (so none trains in the driver)."""
    config = study.benchmark_config()
    jobs = study.jobs(config, list(config.scenes) or benchmark.generated_scenes(config))
    assert jobs and all(job.done for job in jobs)
    trained = {path for path in (output / "runs").rglob("metrics.json") if path.stat().st_mtime >= since}
    assert trained <= {job.result for job in jobs}
    keys = [job.key for job in jobs]
    assert all(key in keys[:index] for index, job in enumerate(jobs) for key in job.after)  # needs come first


def test_run_names_follow_the_trained_set() -> None:
    assert together(("shading",)) == "ssnerf-shading"
    assert together(("shading", "semantics")) == together(("semantics", "shading")) == "ssnerf-semantics+shading"
    assert together(("edges", "keypoints", "shading", "normals", "semantics")) == "ssnerf-all"


@pytest.mark.filterwarnings("ignore")
def test_quick_studies_end_to_end_share_runs_and_resume(tmp_path: Path, monkeypatch) -> None:
    torch.set_num_threads(1)
    output = tmp_path / "studies"
    since = time.time()
    branches = run_study(BranchStudy(quick=True, output=output, properties=("semantics", "edges")))
    assert_planned(BranchStudy(quick=True, output=output, properties=("semantics", "edges")), output, since)
    assert set(branches) == {"walkthrough_seed_0", "walkthrough_seed_1"}
    assert set(branches["walkthrough_seed_0"]) == {"ssnerf-semantics", "ssnerf-semantics-on-v", "ssnerf-edges",
                                       "ssnerf-edges-on-nv", "ssnerf-normals", "ssnerf-normals-pose"}
    report = json.loads((output / "study_branches.json").read_text())
    assert [row["row"] for row in report["tables"]["table3"]] == [
        "F_dec^v (walkthrough_seed_0)", "F_dec^v (walkthrough_seed_1)", "F_dec^v (average)",
        "F_dec^nv (walkthrough_seed_0)", "F_dec^nv (walkthrough_seed_1)", "F_dec^nv (average)"]
    assert all(row["semantics"] is not None and row["edges"] is not None for row in report["tables"]["table3"])
    runs = report["runs"]["walkthrough_seed_0"]
    assert runs["ssnerf-semantics-on-v"]["overrides"] == {"branches": {"semantics": "v"}}
    edges = report["runs"]["walkthrough_seed_0"]["ssnerf-edges"]
    assert report["commit"] and edges["seed"] == 42 and edges["train_seconds"] > 0
    run = output / "runs" / "walkthrough_seed_0" / "ssnerf-edges" / "ssnerf-lite" / "30-steps"
    assert Path(edges["config"]) == run / "config.yml"
    assert "| F_dec^nv (average) |" in (output / "study_branches.md").read_text()
    # the override reached the model: semantics is decoded by F_dec^v in that run
    config = output / "runs" / "walkthrough_seed_0" / "ssnerf-semantics-on-v" / "ssnerf-lite" / "30-steps"
    config = config / "config.yml"
    _, pipeline, _, _ = eval_setup(config, test_mode="test")
    decoders = pipeline.model.sampling.field_module.decoders
    assert "semantics" in decoders["v"].names and "nv" not in decoders

    since = time.time()
    rgb = run_study(RGBStudy(quick=True, output=output, properties=("semantics", "edges")))
    assert_planned(RGBStudy(quick=True, output=output, properties=("semantics", "edges")), output, since)
    assert {"nerf", "ssnerf-semantics-no-rgb", "ssnerf-edges-no-rgb"} <= set(rgb["walkthrough_seed_1"])
    tables = json.loads((output / "study_rgb.json").read_text())["tables"]
    assert [row["row"] for row in tables["table2_left"]] == ["walkthrough_seed_0", "walkthrough_seed_1", "average"]
    assert [row["row"] for row in tables["table2_right"]][:2] == [
        "with RGB (walkthrough_seed_0)", "without RGB (walkthrough_seed_0)"]

    calls = []
    monkeypatch.setattr(benchmark, "train_in_process", lambda config: calls.append(config))
    run_study(BranchStudy(quick=True, output=output, properties=("semantics", "edges")))  # all done: nothing trains
    assert calls == []
    monkeypatch.undo()

    torch.set_num_threads(1)
    since = time.time()
    multitask = run_study(MultiTaskStudy(quick=True, output=output, target="edges", others=("semantics", "normals")))
    assert_planned(MultiTaskStudy(quick=True, output=output, target="edges", others=("semantics", "normals")), output,
                   since)
    assert set(multitask["walkthrough_seed_0"]) == {"ssnerf-edges", "ssnerf-semantics+edges", "ssnerf-normals+edges",
                                        "ssnerf-semantics+normals+edges"}
    table4 = json.loads((output / "study_multitask.json").read_text())["tables"]
    assert list(table4["table4"][0]) == ["row", "alone", "+SL", "+SN", "all"]
    text = (output / "study_multitask.md").read_text()
    assert "(+)" in text or "(−)" in text


@pytest.mark.filterwarnings("ignore")
def test_quick_autolabel_scores_weak_labels_and_renders_on_clean_labels(tmp_path: Path) -> None:
    torch.set_num_threads(1)
    output = tmp_path / "autolabel"
    study = AutoLabelStudy(quick=True, output=output, target="semantics", rates=(0.0, 0.4))
    results = study.run()
    assert_planned(study, output, 0.0)
    assert set(results) == {"walkthrough_seed_0", "walkthrough_seed_1"}
    assert set(results["walkthrough_seed_0"]) == {"0", "0.4"}
    for scene in results.values():
        clean, weak = scene["0"], scene["0.4"]
        assert clean["weak labels, training views"] == 1.0 and clean["weak labels, test views"] == 1.0
        assert weak["weak labels, training views"] < 0.8  # 40% of the pixels relabelled
        assert 0.0 <= weak["SS-NeRF, test views"] <= 1.0
    meta = json.loads((output / "weak" / "walkthrough_seed_0-semantics-0.4-pixels" / "transforms.json").read_text())
    assert meta["ssnerf_weak_labels"]["rate"] == 0.4
    clean_root = output / "scenes" / "walkthrough_seed_0"
    frame = meta["frames"][0]["semantics_file_path"]
    clean_ids = np.asarray(Image.open(clean_root / frame))
    weak_ids = np.asarray(Image.open(output / "weak" / "walkthrough_seed_0-semantics-0.4-pixels" / frame))
    assert (clean_ids != weak_ids).mean() == pytest.approx(0.4, abs=0.01)  # the clean scene itself is untouched
    rows = json.loads((output / "study_autolabel.json").read_text())["tables"]["autolabel"]
    assert [row["row"] for row in rows][:3] == [
        "rate 0 (walkthrough_seed_0)", "rate 0 (walkthrough_seed_1)", "rate 0 (average)"]
    assert (output / "figure_autolabel_semantics.png").is_file()


@pytest.mark.filterwarnings("ignore")
def test_quick_transfer_trains_the_target_on_k_views_from_each_source(tmp_path: Path) -> None:
    torch.set_num_threads(1)
    output = tmp_path / "transfer"
    study = TransferStudy(quick=True, output=output, target="shading", sources=("semantics",), views=3)
    results = study.run()
    assert_planned(study, output, 0.0)
    planned = {job.key: job for job in study.jobs(study.benchmark_config(), benchmark.generated_scenes(
        study.benchmark_config()))}
    assert planned["walkthrough_seed_0-3views/ssnerf-shading-from-semantics/ssnerf-lite/30-steps"].after == (
        "walkthrough_seed_0/ssnerf-semantics/ssnerf-lite/30-steps",)  # a transferred target waits for its source
    assert set(results) == {"walkthrough_seed_0", "walkthrough_seed_1"}
    assert set(results["walkthrough_seed_0"]) == {"Limited Views", "SL → SH"}
    report = json.loads((output / "study_transfer.json").read_text())
    rows = report["tables"]["table5"]
    assert [row["row"] for row in rows] == ["Limited Views", "SL → SH"]
    assert all(row[column] is not None for row in rows
               for column in ("walkthrough_seed_0", "walkthrough_seed_1", "average"))
    views = report["tables"]["train_views"]["walkthrough_seed_0"]
    assert len(views) == 3 and all(name in (output / "study_transfer.md").read_text() for name in views)
    # the transferred run trained on the k views and started from the source model's final checkpoint
    run = output / "runs" / "walkthrough_seed_0-3views" / "ssnerf-shading-from-semantics" / "ssnerf-lite" / "30-steps"
    run = run / "config.yml"
    _, pipeline, _, _ = eval_setup(run, test_mode="test")
    source = output / "runs" / "walkthrough_seed_0" / "ssnerf-semantics" / "ssnerf-lite" / "30-steps"
    source = source / "nerfstudio_models"
    assert pipeline.model.config.encoder_init == source / "step-000000029.ckpt"
    assert [Path(name).name for name in pipeline.datamanager.train_dataset.image_filenames] == [
        Path(name).name for name in views]
    assert report["runs"]["walkthrough_seed_0"]["SL → SH"]["source_run"] == "ssnerf-semantics"
    assert (output / "figure_transfer_walkthrough_seed_0.png").is_file()


@pytest.mark.filterwarnings("ignore")
def test_quick_augmentation_trains_task_networks_on_ground_truth_and_renders(tmp_path: Path) -> None:
    torch.set_num_threads(1)
    output = tmp_path / "augmentation"
    study = AugmentationStudy(quick=True, output=output, properties=("semantics", "normals"))
    results = study.run()
    assert_planned(study, output, 0.0)
    assert set(results) == {"walkthrough_seed_0", "walkthrough_seed_1"}
    assert set(results["walkthrough_seed_0"]) == set(SETTINGS)
    assert all(0.0 <= results[scene][setting]["semantics"] <= 1.0 for scene in results for setting in SETTINGS)
    report = json.loads((output / "study_augmentation.json").read_text())
    assert [row["row"] for row in report["tables"]["table6"]] == list(SETTINGS)
    renders = output / "augmentation" / "ssnerf-lite" / "30-steps" / "renders" / "walkthrough_seed_0"
    same = json.loads((renders / "normals-training-poses" / "transforms.json").read_text())
    novel = json.loads((renders / "normals-novel-poses" / "transforms.json").read_text())
    scene = output / "scenes" / "walkthrough_seed_0"
    train = len(json.loads((scene / "transforms.json").read_text())["train_filenames"])
    assert len(same["frames"]) == train and len(novel["frames"]) == train - 1
    assert novel["frames"][0]["ssnerf_source"]["fraction"] == 0.5
    networks = report["runs"]["task_networks"]
    ground_truth = networks["normals: GT"]["training_images"]
    assert ground_truth == 2 * train  # both scenes pooled
    assert networks["normals: SS-NeRF"]["training_images"] == ground_truth
    assert networks["normals: GT + SS-NeRF"]["training_images"] == 2 * ground_truth
    assert networks["normals: GT + SS-NeRF-N"]["training_images"] == ground_truth + 2 * (train - 1)
    assert (output / "figure_augmentation.png").is_file()


@pytest.mark.filterwarnings("ignore")
def test_quick_sparsity_scores_each_method_against_the_number_of_views(tmp_path: Path) -> None:
    torch.set_num_threads(1)
    output = tmp_path / "sparsity"
    study = SparsityStudy(quick=True, output=output, properties=("semantics", "normals"))
    results = study.run()
    assert set(results) == {"walkthrough_dense_seed_0-6views", "walkthrough_dense_seed_0-3views"}
    assert set(results["walkthrough_dense_seed_0-3views"]) == {
        "nerf", "ssnerf-semantics", "ssnerf-normals", "heuristic", "hybrid", "nearest"}
    assert_planned(study, output, 0.0)
    tables = json.loads((output / "study_sparsity.json").read_text())["tables"]["sparsity"]
    rows = tables["normals"]
    assert [row["row"] for row in rows] == ["6 views", "3 views"]
    assert all(row[f"{method} normals"] is not None for row in rows for method in sparsity.METHODS)
    assert list(sparsity.METHODS)[1:] == list(BASELINE_ROWS.values())  # every Table 1 row without a field
    assert rows[1]["Heuristic normals"] == results["walkthrough_dense_seed_0-3views"]["heuristic"]["normals_l1"]
    copied = rows[1][f"{BASELINE_ROWS['nearest']} normals"]
    assert copied == results["walkthrough_dense_seed_0-3views"]["nearest"]["normals_l1"] != rows[1]["Heuristic normals"]
    # fewer views sit further from the test views (the test views are the same)
    assert rows[1]["median distance (m)"] > rows[0]["median distance (m)"] > 0
    for k in (3, 6):
        meta = json.loads((output / "limited" / f"walkthrough_dense_seed_0-{k}views" / "transforms.json").read_text())
        assert len(meta["train_filenames"]) == k and len(meta["test_filenames"]) == 2
    text = (output / "study_sparsity.md").read_text()
    assert "| 3 views |" in text and "SN l1" in text
    figure = np.asarray(Image.open(output / "figure_sparsity.png"))
    assert figure.std() > 10


def test_seen_pixels_split_each_test_view_by_what_the_labelled_frames_see(trained_scene) -> None:
    from ssnerf_method.data.dataparser import SSNeRFDataParserConfig
    from ssnerf_method.data.dataset import SSNeRFDataset

    parser = SSNeRFDataParserConfig(data=trained_scene[0]).setup()
    train, test = (SSNeRFDataset(parser.get_dataparser_outputs(split)) for split in ("train", "test"))
    one, every = seen_pixels(train, test, [0]), seen_pixels(train, test, list(range(len(train))))
    assert one is not None and every is not None and set(one) == set(every) == set(range(len(test)))
    for index, (seen, unseen) in one.items():
        assert seen.shape == unseen.shape == test[index]["image"].shape[:2]
        assert not (seen & unseen).any() and (seen | unseen).all()  # (a generated room has depth everywhere)
        assert not (seen & ~every[index][0]).any()  # what one frame sees, every frame sees
    assert sum(int(pair[0].sum()) for pair in every.values()) > sum(int(pair[0].sum()) for pair in one.values())
    train.depth_files = None
    assert seen_pixels(train, test, [0]) is None


@pytest.mark.filterwarnings("ignore")
def test_propagation_click_draws_get_folders_and_runs_of_their_own(trained_scene, tmp_path: Path) -> None:
    """Each of `--seeds` draws other clicks into a copy and runs of its own: a second draw into the same output
    folder never reuses the first draw's labels or models. The frame settings, which no seed changes, are shared,
    and a study of several seeds plans each pixel setting once per seed and the others once."""
    scene, _ = trained_scene
    benches = {}
    for seed in (0, 1):
        study = PropagationStudy(quick=True, output=tmp_path, scenes=(scene,), frames=(1,), pixels=(1,), seeds=(seed,))
        made = study.benchmarks(study.benchmark_config())
        assert {key[2] for key in made} == {seed}
        benches[seed] = {setting.name: bench for (_, setting, _), bench in made.items()}
    both = PropagationStudy(quick=True, output=tmp_path, scenes=(scene,), frames=(1,), pixels=(1,), seeds=(0, 1))
    planned = both.benchmarks(both.benchmark_config())
    assert sorted((setting.name, seed) for _, setting, seed in planned) == sorted([
        ("1 frame", 0), ("all frames", 0), *((name, seed) for name in ("1 px/class/frame", "1 px/class/frame, grown")
                                             for seed in (0, 1))])
    assert {bench.folder for bench in planned.values()} == {
        bench.folder for draw in benches.values() for bench in draw.values()}  # the same copies and runs, reused
    with pytest.raises(ValueError, match="--seeds"):
        PropagationStudy(quick=True, output=tmp_path, scenes=(scene,), seeds=()).benchmarks(both.benchmark_config())
    assert benches[0]["1 frame"].folder == benches[1]["1 frame"].folder
    assert benches[0]["all frames"].scene == benches[1]["all frames"].scene == scene
    for name in ("1 px/class/frame", "1 px/class/frame, grown"):
        first, second = benches[0][name], benches[1][name]
        assert first.folder != second.folder and first.scene != second.scene
        assert second.scene.name.endswith("-draw1") and not first.scene.name.endswith("-draw0")

        def labels(bench) -> list:
            """The copy's own label images (the clicks; test frames keep the scene's)."""
            copy = json.loads((bench.scene / "transforms.json").read_text())
            return [np.asarray(Image.open(path)) for path in (frame.get("semantics_file_path") for frame in
                                                              copy["frames"])
                    if path and Path(path).is_relative_to(bench.scene.resolve())]

        drawn = [labels(first), labels(second)]
        assert len(drawn[0]) == len(drawn[1]) > 0
        assert any((a != b).any() for a, b in zip(*drawn))  # other clicks


def test_click_draws_average_into_one_row_with_their_lowest_and_highest() -> None:
    """Several draws of a pixel setting: each scene's row is the mean of its draws (every method, on the test and
    the unlabelled training views) keeping each draw's SS-NeRF; the table's lowest and highest draw are the draws'
    own averages over the scenes, not the extremes of single scenes."""
    def draw(ssnerf: float, heuristic: float) -> Dict[str, Any]:
        return {SSNERF: ssnerf, HEURISTIC: heuristic, ON_TRAIN: {HEURISTIC: heuristic / 2},
                "labelled_pixel_fraction": 0.001, "labelled_test_class_ids": [1, 2]}
    one = draw(0.5, 0.1)
    assert over_draws({0: one}) is one  # a single draw as it is
    assert over_draws({0: one, 1: {"failed": "boom"}}) == {"failed": "boom"}
    a = over_draws({0: draw(0.4, 0.1), 1: draw(0.8, 0.3)})
    assert a[SSNERF] == pytest.approx(0.6) and a[HEURISTIC] == pytest.approx(0.2)
    assert a[ON_TRAIN][HEURISTIC] == pytest.approx(0.1) and a[DRAWS] == {"0": 0.4, "1": 0.8}
    b = over_draws({0: draw(0.6, 0.1), 1: draw(0.4, 0.1)})
    study = PropagationStudy(frames=(), pixels=(1,), grow_scale=0, seeds=(0, 1))
    dense = {SSNERF: 0.9, CLASS_IOU: {"1": 0.9, "2": 0.9}}
    text, tables = study.tables({"a": {"1 px/class/frame": a, ALL_FRAMES: dense},
                                 "b": {"1 px/class/frame": b, ALL_FRAMES: dense}})
    row = next(row for row in tables["propagation"] if row["row"] == "1 px/class/frame")
    assert row[SSNERF] == pytest.approx(0.55)
    assert row[LOWEST] == pytest.approx(0.5) and row[HIGHEST] == pytest.approx(0.6)  # (0.4 + 0.6) / 2, (0.8 + 0.4) / 2
    drawn = tables["per_scene"]["a"]["1 px/class/frame"]
    assert (drawn[DRAW.format(0)], drawn[DRAW.format(1)]) == (0.4, 0.8)
    assert not any(isinstance(value, dict) for value in drawn.values())  # a scene's table has scalar cells
    assert LOWEST in text and "--seeds" in text
    single_text, _ = PropagationStudy(frames=(), pixels=(1,), grow_scale=0).tables({"a": {
        "1 px/class/frame": one, ALL_FRAMES: dense}})
    assert LOWEST not in single_text  # one draw: no draw columns


def test_dense_bound_scores_the_classes_no_label_shows_zero_and_averages_over_every_test_class() -> None:
    dense = {CLASS_IOU: {"1": 0.5, "2": 0.9, "4": 0.4}}
    assert dense_bound({"labelled_test_class_ids": [1, 2, 4]}, dense) == pytest.approx(0.6)
    assert dense_bound({"labelled_test_class_ids": [1, 2]}, dense) == pytest.approx(1.4 / 3)
    assert dense_bound({"labelled_test_class_ids": []}, dense) == 0.0
    assert dense_bound({}, dense) is None and dense_bound({"labelled_test_class_ids": [1]}, {}) is None


def test_quick_propagation_trains_on_fewer_labels_and_reports_their_ceiling(trained_scene, tmp_path: Path) -> None:
    torch.set_num_threads(1)
    scene, _ = trained_scene
    before = (scene / "transforms.json").read_bytes()
    output = tmp_path / "propagation"
    study = PropagationStudy(quick=True, output=output, scenes=(scene,), frames=(1,), pixels=(1,), seeds=(0, 1))
    results = study.run()
    assert (scene / "transforms.json").read_bytes() == before  # the scene itself is not touched
    assert set(results[scene.name]) == {"1 frame", "all frames", "1 px/class/frame", "1 px/class/frame, grown"}
    assert_planned(study, output, 0.0)
    # two click draws: each pixel setting trained twice, its row their mean, a run record per trained model
    report = json.loads((output / "study_propagation.json").read_text())
    assert set(report["runs"][scene.name]) == {"1 frame", "all frames", *(
        f"{name}, draw {seed}" for name in ("1 px/class/frame", "1 px/class/frame, grown") for seed in (0, 1))}
    assert all(run["train_seconds"] > 0 for run in report["runs"][scene.name].values())
    for name in ("1 px/class/frame", "1 px/class/frame, grown"):
        drawn = results[scene.name][name][DRAWS]
        assert set(drawn) == {"0", "1"} and results[scene.name][name][SSNERF] == pytest.approx(np.mean(list(
            drawn.values())))
    assert DRAWS not in results[scene.name]["1 frame"]

    copy = json.loads((output / "propagation" / f"{scene.name}-1frames" / "transforms.json").read_text())
    chosen = {str(Path(name).resolve()) for name in copy["ssnerf_propagation"]["labelled_frames"]}
    test = {str((scene / name).resolve()) for name in copy["test_filenames"]}
    labelled = [frame for frame in copy["frames"] if "semantics_file_path" in frame]
    assert len(chosen) == 1 and {frame["file_path"] for frame in labelled} == chosen | test

    def classes(frames) -> set:
        return {int(value) for frame in frames for value in np.unique(np.asarray(Image.open(
            frame["semantics_file_path"])))} - {255}
    shown = classes(frame for frame in labelled if frame["file_path"] in chosen)
    tested = classes(frame for frame in labelled if frame["file_path"] in test)
    assert shown and tested - shown  # this scene's single labelled frame misses a test class
    sparse = json.loads((output / "propagation" / f"{scene.name}-1pixels" / "transforms.json").read_text())
    for frame in sparse["frames"]:
        if frame["file_path"] not in test and "semantics_file_path" in frame:
            _, counts = np.unique(np.asarray(Image.open(frame["semantics_file_path"])), return_counts=True)
            assert counts[:-1].max() == 1  # one pixel per class, the rest unlabelled (255, sorted last)
    grown = json.loads((output / "propagation" / f"{scene.name}-1pixels-grown300" / "transforms.json").read_text())
    more = 0
    for clicked, frame in zip(sparse["frames"], grown["frames"]):
        if frame["file_path"] not in test and "semantics_file_path" in frame:
            clicks, filled = (np.asarray(Image.open(f["semantics_file_path"])) for f in (clicked, frame))
            np.testing.assert_array_equal(filled[clicks != 255], clicks[clicks != 255])  # the same clicks, kept
            more += int((filled != 255).sum() - (clicks != 255).sum())
    assert more > 0  # grown over their segments

    rows = {row["row"]: row for row in json.loads((output / "study_propagation.json").read_text())["tables"][
        "propagation"]}
    assert rows["1 frame"][CEILING] == pytest.approx(len(tested & shown) / len(tested))
    assert rows["all frames"][CEILING] == 1.0 and rows["all frames"]["SS-NeRF / all frames"] == 1.0
    # the dense model's per-class IoU: they average to its mIoU, and with the unlabelled classes at 0 bound the rows
    dense_iou = results[scene.name]["all frames"][CLASS_IOU]
    assert {int(index) for index in dense_iou} == tested
    assert np.mean(list(dense_iou.values())) == pytest.approx(rows["all frames"]["SS-NeRF"], abs=1e-6)
    assert rows["all frames"][BOUND] == pytest.approx(rows["all frames"]["SS-NeRF"], abs=1e-6)
    assert rows["1 frame"][BOUND] == pytest.approx(sum(dense_iou[str(c)] for c in tested & shown) / len(tested))
    assert rows["1 frame"][BOUND] <= rows["all frames"][BOUND]  # the missing class's IoU is lost
    assert rows["1 px/class/frame"][BOUND] == pytest.approx(rows["all frames"][BOUND])  # clicks show every class
    per_scene = json.loads((output / "study_propagation.json").read_text())["tables"]["per_scene"][scene.name]
    assert per_scene["1 frame"][BOUND] == pytest.approx(rows["1 frame"][BOUND])  # (one scene: its average)
    assert rows["all frames"]["labelled pixels"] == 1.0 > rows["1 frame"]["labelled pixels"] > 0
    assert rows["1 px/class/frame, grown"]["labelled pixels"] == rows["1 px/class/frame"]["labelled pixels"]  # clicks
    # the scene has depth maps: every frame together sees more of the test views than one does, pixels are not frames
    assert 1.0 >= rows["all frames"][SEEN] > rows["1 frame"][SEEN] >= 0 and rows["1 px/class/frame"][SEEN] is None
    for row in rows.values():
        assert all(0.0 <= row[method] <= 1.0 for method in ("SS-NeRF", "Heuristic (labelled frames)", NEAREST_POINT))
    # SS-NeRF scored apart on the test pixels the labelled frames see and on the rest: frame settings only
    for name in ("1 frame", "all frames"):  # (a split with no pixels has no score: this 1 frame sees no test pixel)
        for column, empty in ((ON_SEEN, rows[name][SEEN] == 0.0), (ON_UNSEEN, rows[name][SEEN] == 1.0)):
            assert rows[name][column] is None if empty else 0.0 <= rows[name][column] <= 1.0
    assert rows["all frames"][ON_SEEN] is not None and rows["all frames"][ON_UNSEEN] is not None
    assert rows["1 px/class/frame"][ON_SEEN] is None and rows["1 px/class/frame"][ON_UNSEEN] is None
    assert all(column in (output / "study_propagation.md").read_text() for column in (CEILING, BOUND, ON_UNSEEN))
    assert np.asarray(Image.open(output / "figure_propagation.png")).std() > 10


@pytest.mark.filterwarnings("ignore")
def test_quick_class_grid_study_gives_the_grid_to_the_decoders_it_names(trained_scene, tmp_path: Path) -> None:
    torch.set_num_threads(1)
    scene, _ = trained_scene
    output = tmp_path / "class_grid"
    study = ClassGridStudy(quick=True, output=output, scenes=(scene,), properties=("normals",), gridded=("normals",))
    results = study.run()
    assert_planned(study, output, 0.0)
    expected = {"ssnerf-normals-no-class-grid": (), "ssnerf-normals-class-grid": ("normals",),
                "ssnerf-all-class-grid-semantics": ("semantics",), "ssnerf-all-class-grid-normals": ("normals",)}
    assert set(results[scene.name]) == set(expected)
    for run, gridded in expected.items():
        _, pipeline, _, _ = eval_setup(Path(results[scene.name][run]["config"]), test_mode="test")
        field = pipeline.model.sampling.field_module
        assert tuple(pipeline.model.config.class_grid_properties) == gridded, run
        assert (field.class_grid is not None) == bool(gridded), run  # a normals-only model without: no grid at all
    tables = json.loads((output / "study_class-grid.json").read_text())["tables"]
    assert [row["row"] for row in tables["alone"]] == [
        f"alone, no class grid ({scene.name})", "alone, no class grid (average)",
        f"alone, with the class grid ({scene.name})", "alone, with the class grid (average)"]
    assert all(0.0 <= row["normals"] <= 2.0 for row in tables["alone"])
    for row in tables["all"]:
        assert row["psnr"] > 5.0 and 0.0 <= row["semantics_miou"] <= 1.0, row
    assert "all properties, grid for normals" in (output / "study_class-grid.md").read_text()


@pytest.mark.parametrize("study", [BranchStudy, RGBStudy, MultiTaskStudy, TransferStudy, AugmentationStudy,
                                   AutoLabelStudy, SparsityStudy, PropagationStudy, ClassGridStudy])
def test_a_study_hands_its_launcher_flags_to_the_runs(study, tmp_path: Path) -> None:
    # `ssnerf-study ... --launcher ray` once trained everything locally, one run after another: the flags were dropped
    options = study(output=tmp_path, steps=7, launcher="ray", ray_address="ray://head:10001", cpus_per_run=2.0,
                    gpus_per_run=1.0, retries=5)
    config = options.benchmark_config()
    assert (config.launcher, config.ray_address, config.cpus_per_run, config.gpus_per_run, config.retries) == (
        "ray", "ray://head:10001", 2.0, 1.0, 5)
    assert (config.output, config.steps) == (tmp_path, 7)


def test_propagation_suggested_frames_are_a_row_of_their_own(trained_scene, tmp_path: Path) -> None:
    """`--frame-choice even suggested`: a copy per choice; the suggested copy labels the frames `ssnerf-label
    --suggest-frames` picks from the scene's depth, the even copy evenly spaced ones."""
    from ssnerf_method.experiments.propagation import suggested_frames

    scene, _ = trained_scene
    study = PropagationStudy(quick=True, output=tmp_path, scenes=(scene,), frames=(2,), pixels=(), grow_scale=0,
                             frame_choice=("even", "suggested"))
    planned = {setting.name: bench for (_, setting, _), bench in study.benchmarks(study.benchmark_config()).items()}
    assert set(planned) == {"2 frames", "2 suggested frames", "all frames"}
    kept = {name: json.loads((planned[name].scene / "transforms.json").read_text())["ssnerf_propagation"][
        "labelled_frames"] for name in ("2 frames", "2 suggested frames")}
    assert kept["2 suggested frames"] == sorted(suggested_frames(scene, 2))
    assert kept["2 suggested frames"] != kept["2 frames"] and len(kept["2 frames"]) == 2
