"""Remake the docs' figures of a stroke painted in the viewer (a maintainers' tool; needs chromium, ~10 min on 2 cores):

    .venv/bin/python scripts/label_figures.py [--work /tmp/label_figures] [--docs docs]

A generated room whose semantic labels are given on 4 of its training frames, with the painting's pixels left
unlabelled there (an annotator who skipped a class), trains `ssnerf-lite` briefly. nerfstudio's viewer opens it in
headless Chromium at the training camera that sees the most of the painting: the semantics output is captured
("before"); in the Label panel the class `painting` is picked, "Paint" set to `box: drag`, and a box dragged over the
painting (one stroke, saved to the dataset's strokes.json). Training then resumes from the checkpoint for a few hundred
steps with the stroke mixed into every batch, and the viewer on the resumed run is captured at the same camera
("after"). Writes `docs/label_stroke.png` (before | after, the render only) and `docs/label_panel.png` (the panel
after the stroke).
"""

from __future__ import annotations

import argparse
import copy
import json
import shutil
import sys
import time
from pathlib import Path
from typing import List

import numpy as np
import torch
from PIL import Image, ImageDraw, ImageFont

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from ssnerf_method.data.strokes import STROKES_FILE, StrokeStore  # noqa: E402
from ssnerf_method.engine.trainer import train_in_process  # noqa: E402
from ssnerf_method.experiments.transfer import evenly_spaced  # noqa: E402
from ssnerf_method.label_makers.encoding import SEMANTIC_IGNORE  # noqa: E402
from ssnerf_method.method_configs import ssnerf_lite_config  # noqa: E402
from ssnerf_method.scene.make_scene import MakeSceneConfig, make_scene  # noqa: E402
from ssnerf_method.viewer.label_panel import BOX  # noqa: E402

from browser_driver import (  # noqa: E402
    Chromium,
    ViewerServer,
    click_button,
    crop,
    find_chromium,
    labelled_input_js,
    select_dropdown_option,
    viewport_box,
    wait_for_painting,
    wait_until,
)
from test_viewer_browser import wait_for_viewport  # noqa: E402

TIMEOUT = 300.0
SKIPPED = "painting"
"""The class the annotations leave out, and the stroke paints."""


def scene_with_sparse_labels(root: Path) -> Path:
    """The room (96x72, 24 frames) with semantic labels on 4 evenly spaced training frames, `SKIPPED` unlabelled."""
    scene = root / "scene"
    make_scene(MakeSceneConfig(output_dir=scene, width=96, height=72, num_frames=24, seed=0))
    meta = json.loads((scene / "transforms.json").read_text())
    skipped = meta["semantic_classes"].index(SKIPPED)
    train = [frame["file_path"] for frame in meta["frames"] if frame["file_path"] in meta["train_filenames"]]
    kept = set(evenly_spaced(train, 4))
    for frame in meta["frames"]:
        if frame["file_path"] in meta["test_filenames"]:
            continue
        if frame["file_path"] not in kept:
            del frame["semantics_file_path"]
            continue
        path = scene / frame["semantics_file_path"]
        label = np.asarray(Image.open(path)).copy()
        label[label == skipped] = SEMANTIC_IGNORE
        Image.fromarray(label).save(path)
    (scene / "transforms.json").write_text(json.dumps(meta, indent=2))
    return scene


def train(scene: Path, output: Path, steps: int, load_dir: Path | None = None) -> Path:
    """`ns-train ssnerf-lite` at small sizes (the viewer test's), resumed from `load_dir` when given."""
    torch.manual_seed(0)
    config = copy.deepcopy(ssnerf_lite_config)
    config.pipeline.datamanager.data = scene
    config.pipeline.datamanager.train_num_rays_per_batch = 512
    model = config.pipeline.model
    model.grid_levels, model.grid_max_res, model.grid_log2_hashmap_size = 8, 128, 15
    model.num_proposal_samples, model.num_field_samples, model.eval_num_rays_per_chunk = (32,), 24, 4096
    config.machine.device_type = "cpu"
    config.vis = "tensorboard"
    config.output_dir, config.experiment_name = output, "label"
    config.timestamp = "resumed" if load_dir else "first"
    config.max_num_iterations = config.steps_per_save = steps
    config.steps_per_eval_batch = config.steps_per_eval_image = config.steps_per_eval_all_images = 10**6
    config.logging.local_writer.enable = False
    config.load_dir = load_dir
    train_in_process(config)
    return config.get_base_dir() / "config.yml"


def camera_seeing_most(scene: Path, server: ViewerServer) -> tuple:
    """The training camera whose true labels show the most of `SKIPPED`, and that class's pixel box in it."""
    classes = json.loads((scene / "transforms.json").read_text())["semantic_classes"]
    best = None
    for index, name in enumerate(server.pipeline.datamanager.train_dataset.image_filenames):
        label = np.asarray(Image.open(scene / "semantics" / Path(name).name))
        count = int((label == classes.index(SKIPPED)).sum())
        if best is None or count > best[1]:
            best = (index, count, label == classes.index(SKIPPED))
    rows, columns = np.nonzero(best[2])
    return best[0], (columns.min(), rows.min(), columns.max() + 1, rows.max() + 1), best[2].shape


def opened(browser: Chromium, server: ViewerServer):
    """The browser's page on the viewer, its control panel shown and the training cameras hidden."""
    page = browser.page
    browser.open(server.url)
    page.wait_for(f"!!{labelled_input_js('Output type')}", 60, "the viewer's control panel did not appear")
    click_button(page, "Hide Train Cams")
    return page


def shoot_semantics(page, server: ViewerServer, index: int) -> np.ndarray:
    """The viewport once it shows the full-resolution semantics render at training camera `index`."""
    client = server.wait_for_client(60)
    c2w, fov = server.train_camera(index)
    server.put_client_camera(client, c2w, fov)
    since = time.monotonic()
    select_dropdown_option(page, "Output type", "semantics", timeout=TIMEOUT)
    sent = server.log.wait_for("semantics", since, TIMEOUT, c2w=c2w)
    wait_for_viewport(page, sent.image, TIMEOUT)
    page.evaluate("document.activeElement && document.activeElement.blur()")
    page.evaluate(  # offline, the titlebar's nerfstudio logo is a broken image
        "document.querySelectorAll('img').forEach(i => { if (!i.naturalWidth) i.style.visibility = 'hidden'; })")
    time.sleep(0.3)
    return page.screenshot()


def caption(figure: Image.Image, texts: List[str]) -> Image.Image:
    """`texts` written on white at the top left of each of the figure's equal-width panels."""
    draw = ImageDraw.Draw(figure)
    font = ImageFont.load_default(size=14)
    for index, text in enumerate(texts):
        x = 6 + index * (figure.width + 8) // len(texts)
        draw.rectangle(draw.textbbox((x, 6), text, font=font), fill=(255, 255, 255))
        draw.text((x, 6), text, fill=(0, 0, 0), font=font)
    return figure


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--work", type=Path, default=Path("/tmp/label_figures"))
    parser.add_argument("--docs", type=Path, default=ROOT / "docs")
    parser.add_argument("--steps", type=int, default=600)
    parser.add_argument("--resume-steps", type=int, default=300)
    args = parser.parse_args()
    executable = find_chromium()
    if executable is None:
        raise SystemExit("chromium is not on PATH (Debian's `chromium` package)")
    torch.set_num_threads(1)
    shutil.rmtree(args.work, ignore_errors=True)
    scene = scene_with_sparse_labels(args.work)
    first = train(scene, args.work / "outputs", args.steps)

    with ViewerServer(first, max_res=512) as server, Chromium(executable, args.work / "profile", 1200, 800,
                                                              timeout=60) as browser:
        page = opened(browser, server)
        index, (u0, v0, u1, v1), (height, width) = camera_seeing_most(scene, server)
        before = shoot_semantics(page, server, index)
        box = viewport_box(page)
        left, top, right, bottom = box
        scale = (bottom - top) / height  # the render fills the viewport's height at the training camera's fov

        def on_screen(u: float, v: float) -> tuple:
            return ((left + right) / 2 + (u - width / 2) * scale, top + v * scale)

        select_dropdown_option(page, "Class", f"{server.pipeline.model.class_names.index(SKIPPED)}: {SKIPPED}",
                               timeout=TIMEOUT)
        select_dropdown_option(page, "Paint", BOX, timeout=TIMEOUT)
        wait_for_painting(page, TIMEOUT)
        margin_u, margin_v = 0.15 * (u1 - u0), 0.15 * (v1 - v0)
        page.drag(on_screen(u0 + margin_u, v0 + margin_v), on_screen(u1 - margin_u, v1 - margin_v))
        strokes = scene / STROKES_FILE
        wait_until(lambda: strokes.is_file(), TIMEOUT, "the drag never reached the strokes file")
        page.evaluate(f"{labelled_input_js('Paint')}.scrollIntoView({{block: 'start'}})")
        time.sleep(0.5)
        panel = page.screenshot()
    print(f"{len(StrokeStore.load(strokes).strokes)} stroke, {StrokeStore.load(strokes).num_rays()} rays")

    resumed = train(scene, args.work / "outputs", args.resume_steps, load_dir=first.parent / "nerfstudio_models")
    with ViewerServer(resumed, max_res=512) as server, Chromium(executable, args.work / "profile2", 1200, 800,
                                                                timeout=60) as browser:
        page = opened(browser, server)
        after = shoot_semantics(page, server, index)

    views = [crop(shot, box) for shot in (before, after)]
    gap = np.full((views[0].shape[0], 16, 3), 255, dtype=np.uint8)
    figure = Image.fromarray(np.concatenate([views[0], gap, views[1]], axis=1))
    args.docs.mkdir(parents=True, exist_ok=True)
    caption(figure.resize((figure.width // 2, figure.height // 2), Image.LANCZOS),
            ["before the stroke", f"after {args.resume_steps} steps with it"]).save(args.docs / "label_stroke.png",
                                                                                   optimize=True)
    Image.fromarray(panel[:, box[2]:]).save(args.docs / "label_panel.png", optimize=True)
    print(f"wrote {args.docs / 'label_stroke.png'} and {args.docs / 'label_panel.png'}")


if __name__ == "__main__":
    main()
