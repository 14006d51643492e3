"""Remake the README's two figures from a finished `make demo` (a maintainers' tool; needs chromium):

    .venv/bin/python scripts/readme_figures.py [--demo-output demo_output]

- `docs/summary.png`: the demo's `summary.png` (every property of one test view, ground truth above SS-NeRF), shrunk;
- `docs/viewer_semantics.png`: nerfstudio's viewer in headless Chromium on the demo's trained model, the camera at the
  training view that sees the most of the room (largest median depth), output type `semantics` (the test suite's
  browser driver); the
  same view's `keypoints` goes to `DEMO_OUTPUT/viewer_keypoints.png`.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from PIL import Image

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from browser_driver import (  # noqa: E402
    Chromium,
    ViewerServer,
    click_button,
    find_chromium,
    labelled_input_js,
    select_dropdown_option,
)
from test_viewer_browser import wait_for_viewport  # noqa: E402

TIMEOUT = 180.0
WIDEN = 1.4
"""Field of view of the screenshot's camera, relative to the training camera's."""


def summary(demo: Path, docs: Path, width: int = 1400) -> Path:
    image = Image.open(demo / "summary.png").convert("RGB")
    if image.width > width:
        image = image.resize((width, round(image.height * width / image.width)), Image.LANCZOS)
    target = docs / "summary.png"
    image.save(target, optimize=True)
    return target


def widest_view(scene: Path, names: list) -> int:
    """The training frame that sees the most of the room: the largest median depth."""
    depths = [np.median(np.asarray(Image.open(scene / "depth" / name), dtype=np.float64)) for name in names]
    return int(np.argmax(depths))


def trained_step(config_path: Path) -> int:
    checkpoints = sorted((config_path.parent / "nerfstudio_models").glob("step-*.ckpt"))
    return int(checkpoints[-1].stem.split("-")[1]) + 1 if checkpoints else 0


def viewer_screenshot(demo: Path, docs: Path, max_res: int) -> Path:
    config_path = next((demo / "runs").glob("*/*/demo/config.yml"))
    scene = demo / "scene"
    executable = find_chromium()
    assert executable is not None, "chromium is needed (make system)"
    with ViewerServer(config_path, max_res=max_res) as server, Chromium(
        executable, demo / ".chromium-profile", width=1200, height=800, timeout=TIMEOUT
    ) as browser:
        browser.open(server.url)
        client = server.wait_for_client(TIMEOUT)
        page = browser.page
        page.wait_for(f"!!{labelled_input_js('Output type')}", TIMEOUT, "the viewer's control panel never showed")
        click_button(page, "Hide Train Cams")
        names = [Path(path).name for path in server.pipeline.datamanager.train_dataset.image_filenames]
        index = widest_view(scene, names)
        c2w, fov = server.train_camera(index)
        server.put_client_camera(client, c2w, fov * WIDEN)  # the viewport is squarer than the camera: widen it
        server.viewer.update_step(trained_step(config_path))  # (a loaded model otherwise reads "Step: 0")
        shots = {}
        for output in ("keypoints", "semantics"):  # the keypoint view is kept beside the demo's outputs, to look at
            since = time.monotonic()
            select_dropdown_option(page, "Output type", output, timeout=TIMEOUT)
            sent = server.log.wait_for(output, since=since, timeout=TIMEOUT, c2w=c2w)
            shots[output] = wait_for_viewport(page, sent.image, TIMEOUT)
    Image.fromarray(np.asarray(shots["keypoints"])).save(demo / "viewer_keypoints.png")
    target = docs / "viewer_semantics.png"
    Image.fromarray(np.asarray(shots["semantics"])).save(target, optimize=True)
    return target


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--demo-output", type=Path, default=ROOT / "demo_output")
    parser.add_argument("--max-res", type=int, default=256, help="viewer render resolution (the CPU renders slowly)")
    args = parser.parse_args()
    docs = ROOT / "docs"
    docs.mkdir(exist_ok=True)
    print(summary(args.demo_output, docs))
    print(viewer_screenshot(args.demo_output, docs, args.max_res))


if __name__ == "__main__":
    main()
