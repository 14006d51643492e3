"""nerfstudio's viewer in a real browser, used as a person would.

A tiny `ssnerf-lite` model is trained on a small rendering of the default scene and saved; nerfstudio's viewer loads
the checkpoint (the code path of `ns-viewer --load-config`) in this process, and headless Chromium opens it. The
browser's camera is put at a training pose, then the "Output type" dropdown of the control panel is switched to
`semantics` and to `normals` with mouse clicks, and each time the page is captured once the browser shows the
viewer's new full-resolution image. The semantic screenshot must show the dataset's class colours where the ground
truth of that training frame has those classes; the normals screenshot must look nothing like it. Then the semantics
panel: every class has a legend entry in its colour, and picking one class in "Show class" shows it over RGB.

Needs Debian's `chromium` (the test fails, not skips, without it). Screenshots go to
`$SSNERF_TEST_ARTIFACTS/viewer/` (default: `test_artifacts/viewer/` in the repository).
"""

from __future__ import annotations

import json
import os
import shutil
import time
from pathlib import Path
from typing import Dict, List, Tuple

import numpy as np
import pytest
import torch
from PIL import Image

from nerfstudio.engine.trainer import TrainerConfig

from ssnerf_method.scene.make_scene import MakeSceneConfig, make_scene

from browser_driver import (
    CHROMIUM_PACKAGE_HINT,
    Chromium,
    ViewerServer,
    click_button,
    crop,
    find_chromium,
    labelled_input_js,
    select_dropdown_option,
    viewport_box,
    wait_for_viewport,
)
from test_training import lite_config

REPO = Path(__file__).resolve().parents[1]
WIDTH, HEIGHT, NUM_FRAMES = 64, 48, 12
TRAIN_STEPS = 300
"""About 25 s on one CPU thread; training views' semantics are then ~98% right (walls, floor, bed, paintings)."""
MAX_RES = 128
"""The viewer's "Max res": its full-resolution render is at most 128 px wide (about 1 s per render on the CPU)."""
TIMEOUT = 60.0
"""Limit of each wait (page load, a render reaching the browser, ...)."""
PALETTE_TOLERANCE = 30.0
"""A screenshot pixel shows class c when c's colour is its nearest palette colour and at most this far (RGB L2):
JPEG transport and the browser's texture filtering move colours by a few levels inside regions."""
LARGE_CLASS_SHARE = 0.10
"""Classes covering at least this share of the ground-truth view must show up in the semantic screenshot."""


@pytest.fixture
def single_thread():
    """One intra-op thread, as in the other training tests (2 shared cores stall torch's thread pool)."""
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)


@pytest.fixture
def artifacts_dir() -> Path:
    root = Path(os.environ.get("SSNERF_TEST_ARTIFACTS", REPO / "test_artifacts"))
    path = root / "viewer"
    path.mkdir(parents=True, exist_ok=True)
    for stale in [*path.glob("viewer_*.png"), path / "report.json", path / "chromium.log"]:  # an earlier run's
        stale.unlink(missing_ok=True)
    return path


def tiny_lite_config(scene: Path, output: Path) -> TrainerConfig:
    """The suite's small `ssnerf-lite` (`lite_config`: the benchmark's --quick sizes) with a finer grid and more rays
    and samples, so that after `TRAIN_STEPS` the semantics screenshot shows the scene's classes; ~10k rays/s."""
    config = lite_config(scene, output, TRAIN_STEPS)
    config.pipeline.datamanager.train_num_rays_per_batch = 512
    config.pipeline.datamanager.eval_num_rays_per_batch = 1024
    model = config.pipeline.model
    model.grid_levels, model.grid_max_res, model.grid_log2_hashmap_size = 8, 128, 15
    model.num_proposal_samples, model.num_field_samples = (32,), 24
    model.eval_num_rays_per_chunk = 4096
    model.compile.enabled = False  # (a tiny field: compiling would cost more than its 300 steps)
    config.experiment_name = "viewer"
    config.steps_per_save = TRAIN_STEPS
    config.save_only_latest_checkpoint = True
    return config


def train_and_save(config: TrainerConfig) -> Path:
    """Train as `ns-train` does; return the run's config.yml (its checkpoint is saved after the last step)."""
    torch.manual_seed(0)
    config.save_config()
    trainer = config.setup(local_rank=0, world_size=1)
    trainer.setup()
    trainer.train()
    assert list(config.get_checkpoint_dir().glob("*.ckpt")), "training saved no checkpoint"
    return config.get_base_dir() / "config.yml"


def classify(image: np.ndarray, palette: np.ndarray) -> np.ndarray:
    """(H, W) class id of each pixel's palette colour, -1 where no palette colour is within PALETTE_TOLERANCE."""
    distance = np.linalg.norm(image[..., None, :].astype(np.float64) - palette[None, None].astype(np.float64), axis=-1)
    ids = distance.argmin(axis=-1)
    return np.where(distance.min(axis=-1) <= PALETTE_TOLERANCE, ids, -1)


def shares(ids: np.ndarray, num_classes: int) -> np.ndarray:
    return np.bincount(ids[ids >= 0].ravel(), minlength=num_classes)[:num_classes] / ids.size


def same_view(truth: np.ndarray, view: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """The parts of a training frame's label and of the viewer's viewport that show the same frustum.

    Both cameras share the pose, the vertical field of view and a centred principal point; only the aspect ratio
    differs, so the wider of the two is cropped to the other's aspect around its centre. The viewport crop is then
    sampled at the label's pixel centres.
    """
    truth_aspect = truth.shape[1] / truth.shape[0]
    view_aspect = view.shape[1] / view.shape[0]
    if view_aspect < truth_aspect:
        width = int(round(truth.shape[0] * view_aspect))
        left = (truth.shape[1] - width) // 2
        truth = truth[:, left : left + width]
    else:
        width = int(round(view.shape[0] * truth_aspect))
        left = (view.shape[1] - width) // 2
        view = view[:, left : left + width]
    sampled = np.asarray(Image.fromarray(view).resize((truth.shape[1], truth.shape[0]), Image.NEAREST))
    return truth, sampled


def legend_value_js(entry: str) -> str:
    """JavaScript for the colour ("#rrggbb") of the viser colour input labelled `entry` (viser's ColorInput does not
    carry the label's id, so the input is found in the label's row)."""
    return f"""(() => {{
        const label = Array.from(document.querySelectorAll('label')).find(l => l.textContent === {json.dumps(entry)});
        const row = label && label.closest('.mantine-Flex-root');
        const input = row && row.querySelector('input');
        return input ? input.value : null; }})()"""


def pick_training_view(scene: Path, filenames: List[str], num_classes: int) -> Tuple[int, np.ndarray]:
    """The training frame whose ground-truth semantics has the most classes above LARGE_CLASS_SHARE (first wins)."""
    best, best_count, best_label = 0, -1, None
    for index, name in enumerate(filenames):
        label = np.asarray(Image.open(scene / "semantics" / Path(name).name))
        count = int((shares(label.astype(np.int64), num_classes) >= LARGE_CLASS_SHARE).sum())
        if count > best_count:
            best, best_count, best_label = index, count, label
    assert best_label is not None
    return best, best_label


def test_viewer_output_type_dropdown_in_chromium(tmp_path: Path, single_thread, artifacts_dir: Path) -> None:
    executable = find_chromium()
    if executable is None:
        pytest.fail(f"chromium is not on PATH, and this test drives the viewer in it: {CHROMIUM_PACKAGE_HINT}")
    started = time.monotonic()
    timings: Dict[str, float] = {}

    def mark(name: str) -> None:
        timings[name] = round(time.monotonic() - started, 1)

    scene = tmp_path / "scene"
    make_scene(MakeSceneConfig(output_dir=scene, width=WIDTH, height=HEIGHT, num_frames=NUM_FRAMES, seed=0))
    transforms = json.loads((scene / "transforms.json").read_text())
    classes: List[str] = transforms["semantic_classes"]
    palette = np.asarray(transforms["semantic_colors"], dtype=np.uint8)
    config_path = train_and_save(tiny_lite_config(scene, tmp_path / "outputs"))
    mark("trained")

    report: Dict = {"timings_s": timings}
    browser = None
    try:
        with ViewerServer(config_path, max_res=MAX_RES) as server, Chromium(
            executable, tmp_path / "chromium-profile", width=1200, height=800, timeout=TIMEOUT
        ) as browser:
            page = browser.page
            mark("viewer and browser started")
            renderer = browser.webgl_renderer()
            assert renderer, f"headless chromium has no WebGL 2 (flags: {browser.flags}):\n{browser.log_tail()}"
            report["webgl_renderer"] = renderer

            browser.open(server.url)
            client = server.wait_for_client(TIMEOUT)
            page.wait_for(f"!!{labelled_input_js('Output type')}", TIMEOUT, "the viewer's control panel never showed")
            click_button(page, "Hide Train Cams")  # the frustums of nearby training cameras would cover the view

            # The camera of the training frame with the most large classes; its label is the expected semantics.
            train_names = [Path(p).name for p in server.pipeline.datamanager.train_dataset.image_filenames]
            index, truth = pick_training_view(scene, train_names, len(classes))
            c2w, fov = server.train_camera(index)
            server.put_client_camera(client, c2w, fov)
            rgb = server.log.wait_for("rgb", since=0.0, timeout=TIMEOUT, c2w=c2w)
            rgb_shot = wait_for_viewport(page, rgb.image, TIMEOUT)
            Image.fromarray(rgb_shot).save(artifacts_dir / "viewer_rgb.png")
            mark("first full-resolution render shown")
            report["view"] = {"training_frame": train_names[index], "render_size": list(rgb.image.shape[:2])}

            shots: Dict[str, np.ndarray] = {}
            for output in ("semantics", "normals"):
                since = time.monotonic()
                options = select_dropdown_option(page, "Output type", output, timeout=TIMEOUT)
                report.setdefault("dropdown_options", options)
                image = server.log.wait_for(output, since=since, timeout=TIMEOUT, c2w=c2w)
                Image.fromarray(image.image).save(artifacts_dir / f"viewer_{output}_sent.png")  # what nerfstudio sent
                shots[output] = wait_for_viewport(page, image.image, TIMEOUT)
                Image.fromarray(shots[output]).save(artifacts_dir / f"viewer_{output}.png")
                mark(f"{output} shown")
            box = viewport_box(page)
            # where the class is unsure (where a stroke helps most) is an output of its own
            assert "semantics_uncertainty" in report["dropdown_options"], report["dropdown_options"]

            # The semantics panel under "Custom Elements": one legend entry per class ("id: name" with its colour),
            # and "Show class", which tints one class over a dimmed RGB in the semantics output.
            entries = [f"{number}: {name}" for number, name in enumerate(classes)]
            legend = {entry: page.evaluate(legend_value_js(entry)) for entry in entries}
            report["legend"] = legend
            chosen = int(np.argmax(shares(truth.astype(np.int64), len(classes))))
            select_dropdown_option(page, "Show class", entries[chosen], timeout=TIMEOUT)  # shown with semantics only
            since = time.monotonic()
            select_dropdown_option(page, "Output type", "semantics", timeout=TIMEOUT)
            highlighted = server.log.wait_for("semantics", since=since, timeout=TIMEOUT, c2w=c2w)
            Image.fromarray(highlighted.image).save(artifacts_dir / "viewer_semantics_one_class_sent.png")
            shots["one class"] = wait_for_viewport(page, highlighted.image, TIMEOUT)
            Image.fromarray(shots["one class"]).save(artifacts_dir / "viewer_semantics_one_class.png")
            mark("one class shown")
            plain_semantics = server.log.wait_for("semantics", since=0.0, timeout=TIMEOUT, c2w=c2w).image
    finally:
        if browser is not None and browser.log_path.is_file():
            shutil.copy(browser.log_path, artifacts_dir / "chromium.log")
        (artifacts_dir / "report.json").write_text(json.dumps(report, indent=2, default=str))

    # The viewport (the three.js canvas) without a few pixels of border; the axes gizmo is a negligible corner.
    semantic_view = crop(shots["semantics"], box, margin=2)
    normals_view = crop(shots["normals"], box, margin=2)

    # 1. The two outputs look different.
    difference = np.abs(semantic_view.astype(np.int16) - normals_view.astype(np.int16))
    mean_difference = float(difference.mean())
    changed = float((difference.max(axis=-1) > 40).mean())
    report["semantics_vs_normals"] = {"mean_abs_difference": mean_difference, "changed_share": changed}
    assert mean_difference > 25 and changed > 0.5, (
        f"switching the output type from semantics to normals barely changed the viewport (mean abs. difference "
        f"{mean_difference:.1f}, {changed:.0%} of pixels changed by > 40)"
    )

    # 2. The semantic screenshot is made of the palette's colours, the large ground-truth classes among them.
    semantic_ids = classify(semantic_view, palette)
    palette_share = float((semantic_ids >= 0).mean())
    truth_crop, view_sampled = same_view(truth.astype(np.int64), semantic_view)
    view_ids = classify(view_sampled, palette)
    truth_shares, view_shares = shares(truth_crop, len(classes)), shares(semantic_ids, len(classes))
    agreement = float((view_ids == truth_crop).mean())
    large = [c for c in range(len(classes)) if truth_shares[c] >= LARGE_CLASS_SHARE]
    report["semantics"] = {
        "palette_share": palette_share,
        "agreement_with_ground_truth": agreement,
        "classes": {
            classes[c]: {
                "color": palette[c].tolist(),
                "truth_share": float(truth_shares[c]),
                "shown_share": float(view_shares[c]),
            }
            for c in range(len(classes))
            if truth_shares[c] > 0 or view_shares[c] > 0.005
        },
    }
    (artifacts_dir / "report.json").write_text(json.dumps(report, indent=2, default=str))
    assert large, f"the training view {report['view']} has no class covering {LARGE_CLASS_SHARE:.0%}"
    assert palette_share > 0.85, (
        f"only {palette_share:.0%} of the semantic screenshot's viewport shows class colours of semantic_colors "
        f"(see {artifacts_dir / 'viewer_semantics.png'})"
    )
    missing = {
        classes[c]: (palette[c].tolist(), round(float(truth_shares[c]), 3), round(float(view_shares[c]), 3))
        for c in large
        if view_shares[c] < 0.6 * truth_shares[c]
    }
    assert not missing, (
        f"classes that cover much of the ground truth barely show in the semantic screenshot "
        f"(class: colour, ground-truth share, screenshot share): {missing}"
    )
    assert agreement > 0.75, (
        f"the semantic screenshot agrees with the training frame's labels on only {agreement:.0%} of pixels"
    )

    # 3. Every class has its legend entry, in its colour; one class over RGB is exactly the model's highlight of the
    # rendered semantics and RGB the viewer sent at this pose (pre-JPEG images: a level or two of rounding).
    missing_legend = [entry for entry, value in legend.items() if value is None]
    assert not missing_legend, f"the viewer shows no legend entry for {missing_legend}"
    for (entry, value), colour in zip(legend.items(), palette):
        assert value.lower() == "#" + "".join(f"{int(c):02x}" for c in colour), (entry, value, colour.tolist())
    rgb_sent = rgb.image.astype(np.float64) / 255.0
    grey = (0.299 * rgb_sent[..., 0] + 0.587 * rgb_sent[..., 1] + 0.114 * rgb_sent[..., 2])[..., None]
    in_class = np.abs(plain_semantics.astype(np.int16) - palette[chosen]).max(axis=-1, keepdims=True) <= 1
    expected = np.where(in_class, 0.35 * rgb_sent + 0.65 * palette[chosen] / 255.0, 0.4 * grey) * 255.0
    error = np.abs(highlighted.image.astype(np.float64) - expected)
    report["one_class"] = {"class": classes[chosen], "class_share": float(in_class.mean()),
                           "mean_abs_error": float(error.mean()), "p99_abs_error": float(np.percentile(error, 99))}
    (artifacts_dir / "report.json").write_text(json.dumps(report, indent=2, default=str))
    assert 0.05 < in_class.mean() < 0.95, report["one_class"]
    assert error.mean() < 1.5 and np.percentile(error, 99) < 3.0, report["one_class"]

    # 4. The normals screenshot is not a semantic map: few class colours, and not where the semantic ones are.
    normals_ids = classify(normals_view, palette)
    normals_palette_share = float((normals_ids >= 0).mean())
    same_class = float(((normals_ids == semantic_ids) & (semantic_ids >= 0)).mean())
    report["normals"] = {"palette_share": normals_palette_share, "same_class_as_semantics": same_class}
    (artifacts_dir / "report.json").write_text(json.dumps(report, indent=2, default=str))
    assert normals_palette_share < 0.5 and same_class < 0.3, (
        f"the normals screenshot looks like a semantic map: {normals_palette_share:.0%} of it is in class colours, "
        f"{same_class:.0%} in the same class as the semantic screenshot"
    )
