"""The Label panel in a real browser during a real `ns-train`, and strokes that outlive the run.

`ns-train ssnerf-lite` runs with the viewer (its own process, as a user starts it) on a capture whose frames have no
semantic label file (only the class list). Headless Chromium opens the viewer, picks a class in the Label panel,
switches "Paint" to the brush and clicks the render. The stroke must reach `DATA/ssnerf_labels/strokes.json` while
training runs; then the run is killed with SIGKILL, and the file must still hold the stroke and be loaded by the
next run's datamanager, which mixes its rays, in the painted class, into the training batch.

Needs Debian's `chromium` (the test fails, not skips, without it). Screenshots go to
`$SSNERF_TEST_ARTIFACTS/label/` (default: `test_artifacts/label/` in the repository).
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from PIL import Image

from ssnerf_method.data.datamanager import SSNeRFDataManagerConfig
from ssnerf_method.data.strokes import STROKES_FILE, StrokeStore
from ssnerf_method.scene.make_scene import MakeSceneConfig, make_scene
from ssnerf_method.viewer.label_panel import BRUSH

from browser_driver import (
    CHROMIUM_PACKAGE_HINT,
    Chromium,
    find_chromium,
    free_port,
    labelled_input_js,
    select_dropdown_option,
    viewport_box,
    wait_for_painting,
    wait_until,
)

REPO = Path(__file__).resolve().parents[1]
TIMEOUT = 120.0
QUICK_MODEL = ("--pipeline.model.grid-levels", "4", "--pipeline.model.grid-max-res", "64",
               "--pipeline.model.grid-log2-hashmap-size", "14", "--pipeline.model.grid-hidden-dim", "32",
               "--pipeline.model.decoder-width", "32", "--pipeline.model.num-proposal-samples", "24",
               "--pipeline.model.num-field-samples", "16", "--pipeline.model.proposal-max-res", "64",
               "--pipeline.datamanager.train-num-rays-per-batch", "256", "--pipeline.model.compile.enabled", "False")
"""The benchmark's --quick model sizes, as ns-train flags; eager (its 100000-step run would compile at step 0)."""


def port_open(port: int) -> bool:
    with socket.socket() as sock:
        return sock.connect_ex(("127.0.0.1", port)) == 0


def test_a_stroke_painted_in_the_browser_survives_a_killed_run(tmp_path: Path) -> None:
    executable = find_chromium()
    if executable is None:
        pytest.fail(f"chromium is not on PATH, and this test drives the viewer in it: {CHROMIUM_PACKAGE_HINT}")
    artifacts = Path(os.environ.get("SSNERF_TEST_ARTIFACTS", REPO / "test_artifacts")) / "label"
    artifacts.mkdir(parents=True, exist_ok=True)
    scene = tmp_path / "scene"
    make_scene(MakeSceneConfig(output_dir=scene, width=48, height=36, num_frames=8, seed=0))
    meta = json.loads((scene / "transforms.json").read_text())
    for frame in meta["frames"]:
        del frame["semantics_file_path"]
    (scene / "transforms.json").write_text(json.dumps(meta))
    classes = meta["semantic_classes"]
    port = free_port()
    command = [sys.executable, "-m", "nerfstudio.scripts.train", "ssnerf-lite", "--data", str(scene),
               "--output-dir", str(tmp_path / "outputs"), "--vis", "viewer", "--viewer.websocket-host", "127.0.0.1",
               "--viewer.websocket-port", str(port), "--machine.device-type", "cpu", "--max-num-iterations", "100000",
               "--logging.local-writer.enable", "False", *QUICK_MODEL]
    log = (tmp_path / "ns-train.log").open("w")
    process = subprocess.Popen(command, env={**os.environ, "OMP_NUM_THREADS": "1"}, stdout=log,
                               stderr=subprocess.STDOUT, start_new_session=True)
    strokes = scene / STROKES_FILE
    try:
        wait_until(lambda: port_open(port) or process.poll() is not None, TIMEOUT, "the viewer never opened")
        assert process.poll() is None, (tmp_path / "ns-train.log").read_text()[-3000:]
        with Chromium(executable, tmp_path / "chromium-profile", width=1200, height=800, timeout=TIMEOUT) as browser:
            page = browser.page
            browser.open(f"http://127.0.0.1:{port}")
            page.wait_for(f"!!{labelled_input_js('Paint')}", TIMEOUT, "the Label panel never showed")
            select_dropdown_option(page, "Class", f"{classes.index('wall')}: wall", timeout=TIMEOUT)
            select_dropdown_option(page, "Paint", BRUSH, timeout=TIMEOUT)
            # the server answers by putting the render in pointer mode (viser shows a pointer cursor over it)
            wait_for_painting(page, TIMEOUT)
            left, top, right, bottom = viewport_box(page)
            Image.fromarray(page.screenshot()).save(artifacts / "before_stroke.png")
            page.click_at((left + right) / 2, (top + bottom) / 2)
            wait_until(lambda: strokes.is_file(), TIMEOUT, "the click never reached the strokes file")
            Image.fromarray(page.screenshot()).save(artifacts / "after_stroke.png")
        assert process.poll() is None, "ns-train stopped by itself"
    finally:
        os.killpg(process.pid, signal.SIGKILL)
        process.wait(timeout=30)
        log.close()
    assert process.returncode == -signal.SIGKILL

    store = StrokeStore.load(strokes)  # whole after the kill
    assert [stroke.class_name for stroke in store.strokes] == ["wall"]
    assert 20 <= store.num_rays() <= 40, "the brush's default radius (3 px) paints about 29 pixels"
    assert not list(strokes.parent.glob(".*partial")), "a temporary file of the strokes was left behind"

    started = time.monotonic()
    manager = SSNeRFDataManagerConfig(data=scene).setup(device="cpu", test_mode="val")
    rays = manager.stroke_rays()
    assert rays is not None and len(rays) == store.num_rays() and (rays.class_ids == classes.index("wall")).all()
    bundle, batch = manager.next_train(0)
    painted = manager.config.stroke_rays_per_batch
    assert len(bundle) == manager.config.train_num_rays_per_batch + painted
    assert (batch["semantics"][-painted:, 0] == classes.index("wall")).all()
    assert time.monotonic() - started < 60
