"""Drive nerfstudio's web viewer in a real browser, as a person would: a minimal Chrome DevTools Protocol client.

No selenium or playwright: Debian's `chromium` is started headless with remote debugging, and this module speaks the
DevTools protocol (JSON over a websocket) with the `websockets` package that viser already depends on. Pieces:

- `Chromium`: launch / quit the browser (its own process group, a throwaway profile), with software WebGL
  (SwiftShader) so the viser client can draw the rendered image into its three.js canvas without a GPU.
- `Page`: evaluate JavaScript, poll for a condition, click with real mouse events (`Input.dispatchMouseEvent`),
  take screenshots (`Page.captureScreenshot`).
- viser / nerfstudio helpers: pick an option of a labelled viser dropdown (a Mantine `Select`) by clicking it, find
  the 3D viewport, and `ViewerServer`, which runs nerfstudio's viewer in this process on a trained checkpoint (the
  code path of `ns-viewer`) and records every image it sends to the browser.

Run as a script, it saves a README screenshot of the viewer showing one output (default `semantics`):

    python tests/browser_driver.py --load-config RUN/config.yml --output docs/viewer_semantics.png
"""

from __future__ import annotations

import argparse
import base64
import contextlib
import io
import json
import math
import os
import shutil
import signal
import socket
import subprocess
import tempfile
import threading
import time
import urllib.request
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Dict, Iterator, List, Optional, Sequence, Tuple

import numpy as np
from PIL import Image
from websockets.sync.client import ClientConnection, connect

CHROMIUM_FLAGS: Tuple[str, ...] = (
    "--headless=new",
    "--no-sandbox",  # runs as root in containers
    "--disable-gpu",  # no GPU process for rasterisation ...
    "--use-angle=swiftshader",  # ... but WebGL through ANGLE on SwiftShader, a CPU implementation
    "--enable-unsafe-swiftshader",  # Chromium >= 137 refuses the SwiftShader WebGL fallback without it
    "--disable-dev-shm-usage",
    "--no-first-run",
    "--no-default-browser-check",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--mute-audio",
    "--hide-scrollbars",
)
"""Flags that give a headless Chromium a working WebGL 2 context without a GPU (ANGLE on SwiftShader)."""

CHROMIUM_PACKAGE_HINT = "install Debian's `chromium` package (`sudo apt-get install chromium`; `make test` installs it)"


class CDPError(RuntimeError):
    """A DevTools command failed, a page script threw, or the browser went away."""


def find_chromium() -> Optional[str]:
    """The `chromium` executable on PATH (Debian's package), or None."""
    return shutil.which("chromium")


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port that is free right now on `host`."""
    with socket.socket() as sock:
        sock.bind((host, 0))
        return int(sock.getsockname()[1])


def _http_json(url: str, timeout: float) -> Any:
    """GET a JSON document, never through a proxy (the DevTools endpoint is local)."""
    opener = urllib.request.build_opener(urllib.request.ProxyHandler({}))
    with opener.open(url, timeout=timeout) as response:
        return json.loads(response.read().decode())


def wait_until(condition: Callable[[], Any], timeout: float, message: str | Callable[[], str], interval: float = 0.1):
    """Poll `condition` until it returns something truthy (returned); raise TimeoutError with `message` otherwise."""
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            text = message() if callable(message) else message
            raise TimeoutError(f"{text} (waited {timeout:.0f} s)")
        time.sleep(interval)


class Page:
    """One page target, driven over its DevTools websocket. Commands are synchronous; events are kept in order."""

    def __init__(self, websocket_url: str, timeout: float = 30.0):
        self.timeout = timeout
        self._stack = contextlib.ExitStack()
        # no proxy (the endpoint is local), no size limit (screenshots), no keepalive pings (long page scripts)
        self._ws: ClientConnection = self._stack.enter_context(
            connect(
                websocket_url, max_size=None, proxy=None, open_timeout=timeout, compression=None, ping_interval=None
            )
        )
        self._next_id = 0
        self.events: List[Dict[str, Any]] = []

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self._stack.close()

    def call(self, method: str, timeout: Optional[float] = None, **params: Any) -> Dict[str, Any]:
        """Send one DevTools command and wait for its answer (events that arrive meanwhile go to `events`)."""
        self._next_id += 1
        command_id = self._next_id
        self._ws.send(json.dumps({"id": command_id, "method": method, "params": params}))
        deadline = time.monotonic() + (self.timeout if timeout is None else timeout)
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise CDPError(f"no answer to DevTools command {method} within {timeout or self.timeout:.0f} s")
            try:
                message = json.loads(self._ws.recv(timeout=remaining))
            except TimeoutError:
                continue
            except Exception as err:  # the browser died or closed the connection
                raise CDPError(f"DevTools connection lost during {method}: {err!r}") from err
            if message.get("id") == command_id:
                if "error" in message:
                    raise CDPError(f"{method} failed: {message['error']}")
                return message.get("result", {})
            if "method" in message:
                self.events.append(message)

    # -- JavaScript -------------------------------------------------------------------------------------------------

    def evaluate(self, expression: str, timeout: Optional[float] = None) -> Any:
        """Evaluate a JavaScript expression in the page (promises awaited) and return its JSON value."""
        result = self.call(
            "Runtime.evaluate", timeout=timeout, expression=expression, returnByValue=True, awaitPromise=True
        )
        if "exceptionDetails" in result:
            details = result["exceptionDetails"]
            text = details.get("exception", {}).get("description") or details.get("text")
            raise CDPError(f"page script threw: {text}\n--- script ---\n{expression}")
        return result.get("result", {}).get("value")

    def wait_for(self, expression: str, timeout: float, message: str, interval: float = 0.1) -> Any:
        """Poll a JavaScript expression until it is truthy; return its value."""
        return wait_until(lambda: self.evaluate(expression), timeout, message, interval)

    # -- input ------------------------------------------------------------------------------------------------------

    def click_at(self, x: float, y: float) -> None:
        """A left click at viewport coordinates (CSS pixels): move, press, release, as a mouse does."""
        self.call("Input.dispatchMouseEvent", type="mouseMoved", x=x, y=y, button="none", buttons=0)
        self.call("Input.dispatchMouseEvent", type="mousePressed", x=x, y=y, button="left", buttons=1, clickCount=1)
        self.call("Input.dispatchMouseEvent", type="mouseReleased", x=x, y=y, button="left", buttons=0, clickCount=1)

    def drag(self, start: Tuple[float, float], end: Tuple[float, float], steps: int = 8) -> None:
        """A left-button drag from `start` to `end` (viewport coordinates, CSS pixels), through `steps` moves."""
        self.call("Input.dispatchMouseEvent", type="mouseMoved", x=start[0], y=start[1], button="none", buttons=0)
        self.call("Input.dispatchMouseEvent", type="mousePressed", x=start[0], y=start[1], button="left", buttons=1,
                  clickCount=1)
        for step in range(1, steps + 1):
            x = start[0] + (end[0] - start[0]) * step / steps
            y = start[1] + (end[1] - start[1]) * step / steps
            self.call("Input.dispatchMouseEvent", type="mouseMoved", x=x, y=y, button="left", buttons=1)
        self.call("Input.dispatchMouseEvent", type="mouseReleased", x=end[0], y=end[1], button="left", buttons=0,
                  clickCount=1)

    def click_element(self, element_js: str, what: str) -> None:
        """Scroll the element that `element_js` evaluates to into view and click its centre with the mouse.

        Fails when the element is missing, has no size, or is covered by another element at its centre (a person
        could not click it either).
        """
        box = self.evaluate(
            f"""(() => {{
                const el = ({element_js});
                if (!el) return {{error: 'missing'}};
                el.scrollIntoView({{block: 'nearest', inline: 'nearest'}});
                const r = el.getBoundingClientRect();
                if (r.width < 1 || r.height < 1) return {{error: 'not visible (zero size)'}};
                const x = r.left + r.width / 2, y = r.top + r.height / 2;
                const hit = document.elementFromPoint(x, y);
                if (!hit || !(hit === el || el.contains(hit) || hit.contains(el)))
                    return {{error: 'covered by ' + (hit ? hit.outerHTML.slice(0, 200) : 'nothing')}};
                return {{x, y}};
            }})()"""
        )
        if "error" in box:
            raise CDPError(f"cannot click {what}: {box['error']}")
        self.click_at(box["x"], box["y"])

    # -- output -----------------------------------------------------------------------------------------------------

    def screenshot(self) -> np.ndarray:
        """The visible page as an (H, W, 3) uint8 RGB array (PNG from `Page.captureScreenshot`)."""
        data = self.call("Page.captureScreenshot", format="png", captureBeyondViewport=False)["data"]
        return np.asarray(Image.open(io.BytesIO(base64.b64decode(data))).convert("RGB"))


class Chromium:
    """A headless Chromium with remote debugging and one page; a context manager that always quits the browser."""

    def __init__(
        self,
        executable: str,
        profile_dir: Path,
        width: int = 1200,
        height: int = 800,
        flags: Sequence[str] = CHROMIUM_FLAGS,
        timeout: float = 30.0,
    ):
        self.executable, self.profile_dir, self.width, self.height = executable, Path(profile_dir), width, height
        self.flags, self.timeout = tuple(flags), timeout
        self.process: Optional[subprocess.Popen] = None
        self.page: Optional[Page] = None
        self.log_path = self.profile_dir.parent / f"{self.profile_dir.name}.log"

    def __enter__(self) -> "Chromium":
        try:
            self.start()
        except BaseException:
            self.quit()
            raise
        return self

    def __exit__(self, *exc_info) -> None:
        self.quit()

    def log_tail(self, lines: int = 15) -> str:
        with contextlib.suppress(OSError):
            return "\n".join(self.log_path.read_text(errors="replace").splitlines()[-lines:])
        return ""

    def start(self) -> None:
        self.profile_dir.mkdir(parents=True, exist_ok=True)
        port_file = self.profile_dir / "DevToolsActivePort"
        port_file.unlink(missing_ok=True)  # a reused profile's stale port
        command = [
            self.executable,
            *self.flags,
            "--remote-debugging-port=0",  # the browser picks a free port and writes it to DevToolsActivePort
            f"--user-data-dir={self.profile_dir}",
            f"--window-size={self.width},{self.height}",
            "about:blank",
        ]
        with open(self.log_path, "wb") as log:
            # a new session (process group) so that quitting ends the browser's helper processes too
            self.process = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)

        def devtools_port() -> Optional[int]:
            if self.process is not None and self.process.poll() is not None:
                raise CDPError(f"chromium exited with code {self.process.returncode}:\n{self.log_tail()}")
            with contextlib.suppress(OSError, ValueError, IndexError):
                return int(port_file.read_text().split()[0])
            return None

        port = wait_until(
            devtools_port, self.timeout, lambda: f"chromium wrote no DevToolsActivePort:\n{self.log_tail()}"
        )

        def page_targets() -> List[Dict[str, Any]]:
            with contextlib.suppress(OSError, ValueError):
                return [t for t in _http_json(f"http://127.0.0.1:{port}/json/list", 5) if t.get("type") == "page"]
            return []

        targets = wait_until(
            page_targets,
            self.timeout,
            "chromium lists no page target on its DevTools endpoint",
        )
        self.page = Page(targets[0]["webSocketDebuggerUrl"], timeout=self.timeout)
        self.page.call("Page.enable")
        # The layout viewport is exactly width x height CSS pixels (headless windows lose some height otherwise).
        self.page.call(
            "Emulation.setDeviceMetricsOverride",
            width=self.width,
            height=self.height,
            deviceScaleFactor=1,
            mobile=False,
        )

    def open(self, url: str, ready_js: str = "document.readyState === 'complete'") -> None:
        """Navigate the page and wait until `ready_js` holds."""
        assert self.page is not None
        self.page.call("Page.navigate", url=url)
        self.page.wait_for(ready_js, self.timeout, f"{url} did not finish loading in chromium")

    def webgl_renderer(self) -> Optional[str]:
        """The WebGL renderer string of a fresh context, or None when WebGL is unavailable."""
        assert self.page is not None
        return self.page.evaluate(
            """(() => { const gl = document.createElement('canvas').getContext('webgl2');
                 if (!gl) return null; const info = gl.getExtension('WEBGL_debug_renderer_info');
                 return info ? gl.getParameter(info.UNMASKED_RENDERER_WEBGL) : gl.getParameter(gl.RENDERER); })()"""
        )

    def quit(self) -> None:
        if self.page is not None:
            with contextlib.suppress(Exception):
                self.page.call("Browser.close", timeout=5)
            self.page.close()
            self.page = None
        if self.process is not None:
            if self.process.poll() is None:
                with contextlib.suppress(subprocess.TimeoutExpired):
                    self.process.wait(timeout=5)
            for sig in (signal.SIGTERM, signal.SIGKILL):
                with contextlib.suppress(ProcessLookupError, PermissionError):
                    os.killpg(self.process.pid, sig)  # our own session: the browser and its helpers only
                with contextlib.suppress(subprocess.TimeoutExpired):
                    self.process.wait(timeout=5)
                    break
            self.process = None


# ---- the viser control panel (nerfstudio viewer) ------------------------------------------------------------------

def _js(value: str) -> str:
    return json.dumps(value)


def labelled_input_js(label: str) -> str:
    """JavaScript for the input of a viser GUI element labelled exactly `label`.

    viser renders each labelled input as `<label for=ID>LABEL</label>` next to the Mantine input whose `id` is ID.
    """
    return f"""(() => {{
        const label = Array.from(document.querySelectorAll('label[for]')).find(l => l.textContent === {_js(label)});
        return label ? document.getElementById(label.htmlFor) : null; }})()"""


def dropdown_options(page: Page, label: str) -> List[str]:
    """The option texts of the open dropdown of the viser Select labelled `label` (its listbox, via aria-controls)."""
    return page.evaluate(
        f"""(() => {{ const input = {labelled_input_js(label)};
            const box = input && document.getElementById(input.getAttribute('aria-controls'));
            return box ? Array.from(box.querySelectorAll('[role=option]')).map(o => o.textContent.trim()) : []; }})()"""
    )


def select_dropdown_option(page: Page, label: str, option: str, timeout: float = 15.0) -> List[str]:
    """Choose `option` (exact text) in the viser dropdown labelled `label` by clicking, as a person does.

    Clicks the Mantine Select's input to open its listbox (`aria-controls` of the input names it), waits for the
    options, clicks the `[role=option]` whose text is exactly `option`, and waits until the input shows it. Returns
    the option texts that the open dropdown listed.
    """
    page.wait_for(f"!!{labelled_input_js(label)}", timeout, f"no viser input labelled {label!r} in the page")
    page.click_element(labelled_input_js(label), f"the {label!r} dropdown")
    # The open list follows the server: nerfstudio fills it with the model's outputs after its first render.
    listed: List[str] = []

    def offered() -> bool:
        listed[:] = dropdown_options(page, label)
        return option in listed

    wait_until(offered, timeout, lambda: f"the {label!r} dropdown lists no option {option!r}; it lists {listed}")
    options = list(listed)
    page.click_element(
        f"""(() => {{ const input = {labelled_input_js(label)};
            const box = document.getElementById(input.getAttribute('aria-controls'));
            return Array.from(box.querySelectorAll('[role=option]')).find(o => o.textContent.trim() === {_js(option)});
        }})()""",
        f"option {option!r} of the {label!r} dropdown",
    )
    page.wait_for(
        f"(() => {{ const input = {labelled_input_js(label)}; return input && input.value === {_js(option)}; }})()",
        timeout,
        f"the {label!r} dropdown does not show {option!r} after clicking it",
    )
    return options


def click_button(page: Page, text: str) -> None:
    """Click the visible button whose text is exactly `text`."""
    page.click_element(
        f"""Array.from(document.querySelectorAll('button')).find(
                b => b.textContent.trim() === {_js(text)} && b.getBoundingClientRect().width > 0)""",
        f"button {text!r}",
    )


def viewport_box(page: Page) -> Tuple[int, int, int, int]:
    """(left, top, right, bottom) in CSS pixels of viser's three.js canvas, the 3D viewport."""
    box = page.evaluate(
        """(() => { const c = document.querySelector('canvas[data-engine^="three.js"]');
            if (!c) return null; const r = c.getBoundingClientRect();
            return [r.left, r.top, r.right, r.bottom]; })()"""
    )
    if not box:
        raise CDPError("the page has no three.js canvas (viser's viewport)")
    left, top, right, bottom = (int(round(v)) for v in box)
    return left, top, right, bottom


def wait_for_painting(page: Page, timeout: float) -> None:
    """Wait until the viewport takes the pointer for painting: viser shows a pointer cursor over the render once the
    server has registered a scene pointer callback (the Label panel's "Paint")."""
    page.wait_for("document.querySelector('canvas[data-engine^=\"three.js\"]').style.cursor === 'pointer'",
                  timeout, "the render never switched to painting")


def crop(image: np.ndarray, box: Tuple[int, int, int, int], margin: int = 0) -> np.ndarray:
    left, top, right, bottom = box
    return image[top + margin : bottom - margin, left + margin : right - margin]


def resize(image: np.ndarray, height: int, width: int) -> np.ndarray:
    """Area-average resize of an (H, W, 3) uint8 image."""
    return np.asarray(Image.fromarray(image).resize((width, height), Image.BOX))


# ---- nerfstudio's viewer, in this process -------------------------------------------------------------------------

@dataclass
class SentImage:
    """One image the viewer sent to the browser (before viser's JPEG encoding)."""

    time: float
    output: str
    """The viewer's "Output type" when it was sent."""
    state: str
    """The render state machine's state: "low_move", "low_static" or "high" (full "Max res")."""
    c2w: np.ndarray
    """(3, 4) camera-to-world (nerfstudio's world) of the render."""
    image: np.ndarray
    """(H, W, 3) uint8."""


@dataclass
class RenderLog:
    """Every image nerfstudio's viewer sends to a browser, recorded by wrapping its render state machine."""

    images: List[SentImage] = field(default_factory=list)
    _lock: threading.Lock = field(default_factory=threading.Lock)

    @contextlib.contextmanager
    def installed(self) -> Iterator["RenderLog"]:
        from nerfstudio.viewer.render_state_machine import RenderStateMachine

        original_render, original_send = RenderStateMachine._render_img, RenderStateMachine._send_output_to_viewer
        log = self

        def render_img(machine, camera_state):
            machine._logged_c2w = camera_state.c2w.detach().cpu().numpy().copy()
            return original_render(machine, camera_state)

        def send_output(machine, outputs, static_render=True):
            scene = machine.client.scene
            if not getattr(scene, "_render_log_wrapped", False):
                set_background = scene.set_background_image

                def recording(image, *args, **kwargs):
                    set_background(image, *args, **kwargs)
                    sent = SentImage(
                        time.monotonic(), machine._logged_output, machine.state, machine._logged_c2w,
                        np.array(image, copy=True),
                    )
                    with log._lock:
                        log.images.append(sent)

                scene.set_background_image = recording
                scene._render_log_wrapped = True
            machine._logged_output = machine.viewer.control_panel.output_render
            return original_send(machine, outputs, static_render)

        RenderStateMachine._render_img = render_img
        RenderStateMachine._send_output_to_viewer = send_output
        try:
            yield self
        finally:
            RenderStateMachine._render_img = original_render
            RenderStateMachine._send_output_to_viewer = original_send

    def snapshot(self) -> List[SentImage]:
        with self._lock:
            return list(self.images)

    def wait_for(
        self,
        output: str,
        since: float,
        timeout: float,
        c2w: Optional[np.ndarray] = None,
        state: str = "high",
    ) -> SentImage:
        """The first image sent after `since` with this output and render state (and camera, when given)."""

        def matching() -> Optional[SentImage]:
            for sent in self.snapshot():
                if sent.time >= since and sent.output == output and sent.state == state:
                    if c2w is None or np.allclose(sent.c2w, c2w, atol=2e-3):
                        return sent
            return None

        def describe() -> str:
            recent = [(s.output, s.state, s.image.shape[:2]) for s in self.snapshot() if s.time >= since]
            return f"the viewer sent no {state!r} {output!r} image at the requested camera; since then it sent {recent}"

        return wait_until(matching, timeout, describe, interval=0.05)


class ViewerServer:
    """nerfstudio's viewer on a trained run, in this process: what `ns-viewer --load-config CONFIG` starts.

    `RunViewer.main` / `_start_viewer` (nerfstudio/scripts/viewer/run_viewer.py) without the endless loop:
    `eval_setup` loads the checkpoint, `Viewer` starts the viser server, `init_scene` adds the training cameras.
    """

    def __init__(self, config_path: Path, port: Optional[int] = None, max_res: Optional[int] = None):
        self.config_path, self.requested_port, self.max_res = Path(config_path), port, max_res
        self.log = RenderLog()
        self._stack = contextlib.ExitStack()
        self.viewer = None
        self.pipeline = None

    def __enter__(self) -> "ViewerServer":
        try:
            self.start()
        except BaseException:
            self.stop()
            raise
        return self

    def __exit__(self, *exc_info) -> None:
        self.stop()

    def start(self) -> None:
        # eval_utils before writer: nerfstudio's imports are circular, and writer first fails in a fresh process
        from nerfstudio.utils.eval_utils import eval_setup  # noqa: I001
        from nerfstudio.utils import writer
        from nerfstudio.viewer.viewer import Viewer

        config, pipeline, _, step = eval_setup(self.config_path, eval_num_rays_per_chunk=None, test_mode="test")
        self.pipeline = pipeline
        config.vis = "viewer"
        config.viewer.websocket_host = "127.0.0.1"
        config.viewer.websocket_port = self.requested_port or free_port()
        config.logging.local_writer.enable = False
        self._stack.enter_context(self.log.installed())
        self.viewer = Viewer(
            config.viewer,
            log_filename=config.get_base_dir() / config.viewer.relative_log_filename,
            datapath=pipeline.datamanager.get_datapath(),
            pipeline=pipeline,
            share=False,
            train_lock=threading.Lock(),
        )
        writer.setup_local_writer(config.logging, max_iter=config.max_num_iterations, banner_messages=None)
        self.viewer.init_scene(
            train_dataset=pipeline.datamanager.train_dataset,
            train_state="completed",
            eval_dataset=pipeline.datamanager.eval_dataset,
        )
        self.viewer.update_scene(step=step)
        if self.max_res is not None:
            # the "Max res" slider of the control panel: the full-resolution render's longer side, in pixels
            self.viewer.control_panel._max_res.value = self.max_res

    @property
    def port(self) -> int:
        return self.viewer.viser_server.get_port()

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def stop(self) -> None:
        viewer, self.viewer = self.viewer, None
        if viewer is not None:
            machines = list(viewer.render_statemachines.values())
            for machine in machines:
                machine.running = False
                machine.interrupt_render_flag = True  # aborts a render in progress (nerfstudio's own mechanism)
            with contextlib.suppress(Exception):
                viewer.viser_server.stop()
            for machine in machines:
                machine.join(timeout=10)
        self._stack.close()

    def wait_for_client(self, timeout: float):
        """The viser client handle of the (one) browser tab, once it has sent its camera."""
        return wait_until(
            lambda: next(iter(self.viewer.viser_server.get_clients().values()), None),
            timeout,
            "no browser connected to the viewer's websocket",
        )

    def train_camera(self, index: int) -> Tuple[np.ndarray, float]:
        """(3, 4) camera-to-world (nerfstudio's world) and vertical field of view (radians) of a training camera."""
        cameras = self.pipeline.datamanager.train_dataset.cameras
        c2w = cameras.camera_to_worlds[index].cpu().numpy().astype(np.float64)
        fov = 2.0 * math.atan(float(cameras.cy[index]) / float(cameras.fy[index]))
        return c2w, fov

    def put_client_camera(self, client, c2w: np.ndarray, fov: float, timeout: float = 20.0) -> None:
        """Move the browser's camera to `c2w` with vertical field of view `fov`, and wait until it reports back.

        The same conversion as the viewer's click on a training camera (`Viewer.init_scene`): viser cameras look
        along +z with y down (OpenCV), nerfstudio's along -z with y up, and viser's world is 10x nerfstudio's.
        """
        import viser.transforms as vtf

        from nerfstudio.viewer.viewer import VISER_NERFSTUDIO_SCALE_RATIO

        rotation = vtf.SO3.from_matrix(c2w[:3, :3]) @ vtf.SO3.from_x_radians(np.pi)
        position = c2w[:3, 3] * VISER_NERFSTUDIO_SCALE_RATIO
        with client.atomic():
            client.camera.fov = fov
            client.camera.position = position
            client.camera.wxyz = rotation.wxyz

        def arrived() -> bool:
            state = self.viewer.get_camera_state(client)
            return bool(
                np.allclose(state.c2w.numpy(), c2w, atol=1e-3) and abs(client.camera.fov - fov) < 1e-3
            )

        wait_until(arrived, timeout, "the browser's camera did not move to the requested training pose")


# ---- README screenshot --------------------------------------------------------------------------------------------

def viewport_difference(page: Page, shot: np.ndarray, expected: np.ndarray) -> float:
    """Mean absolute difference (0-255) between a screenshot's 3D viewport, shrunk to `expected`'s size, and
    `expected`."""
    view = resize(crop(shot, viewport_box(page)), *expected.shape[:2])
    return float(np.abs(view.astype(np.float64) - expected.astype(np.float64)).mean())


def wait_for_viewport(page: Page, expected: np.ndarray, timeout: float, tolerance: float = 8.0) -> np.ndarray:
    """Screenshots until the 3D viewport shows `expected` (an image the viewer sent); returns the screenshot.

    Shown means: the control panel's stats read the image's resolution ("Resolution: WxHpx", which the viewer
    updates right after each image), the viewport is within `tolerance` of the image, and two consecutive
    screenshots agree (the browser has finished decoding and drawing it; a low-resolution preview of the same
    view would also be close to `expected`, but not with that resolution in the stats).
    """
    height, width = expected.shape[:2]
    resolution = f"Resolution: {width}x{height}px"
    last: Dict[str, Any] = {"error": math.inf, "stats": None, "previous": None}

    def shown() -> Optional[List[np.ndarray]]:
        stats = page.evaluate("document.body.innerText.includes(" + _js(resolution) + ")")
        shot = page.screenshot()
        error = viewport_difference(page, shot, expected)
        previous, last["previous"] = last["previous"], shot
        last.update(error=error, stats=stats)
        if not stats or error > tolerance or previous is None:
            return None
        steady = viewport_difference(page, previous, resize(crop(shot, viewport_box(page)), height, width)) < 1.0
        return [shot] if steady else None

    return wait_until(
        shown,
        timeout,
        lambda: (
            f"the browser's viewport never showed the viewer's {width}x{height} image: last mean abs. difference "
            f"{last['error']:.1f} (tolerance {tolerance}), stats text {resolution!r} shown: {last['stats']}"
        ),
        interval=0.15,
    )[0]


def save_viewer_screenshot(
    config_path: Path,
    output_path: Path,
    output_type: str = "semantics",
    camera_index: int = 0,
    max_res: int = 512,
    width: int = 1200,
    height: int = 800,
    timeout: float = 300.0,
) -> Path:
    """Open the viewer on a trained run in headless Chromium, put the camera at a training pose, pick
    `output_type` in the "Output type" dropdown, and save the page once it shows the full-resolution render."""
    executable = find_chromium()
    if executable is None:
        raise SystemExit(f"chromium is not on PATH: {CHROMIUM_PACKAGE_HINT}")
    with contextlib.ExitStack() as stack:
        tmp = stack.enter_context(tempfile.TemporaryDirectory(prefix="viewer-shot-"))
        server = stack.enter_context(ViewerServer(config_path, max_res=max_res))
        browser = stack.enter_context(Chromium(executable, Path(tmp) / "profile", width, height, timeout=60))
        page = browser.page
        browser.open(server.url)
        client = server.wait_for_client(60)
        page.wait_for(f"!!{labelled_input_js('Output type')}", 60, "the viewer's control panel did not appear")
        click_button(page, "Hide Train Cams")
        c2w, fov = server.train_camera(camera_index)
        server.put_client_camera(client, c2w, fov)
        server.log.wait_for("rgb", since=0.0, timeout=timeout, c2w=c2w)
        since = time.monotonic()
        select_dropdown_option(page, "Output type", output_type)
        sent = server.log.wait_for(output_type, since, timeout, c2w=c2w)
        shot = wait_for_viewport(page, sent.image, 60)
        page.evaluate("document.activeElement && document.activeElement.blur()")  # no focus ring in the picture
        # Offline, the titlebar's nerfstudio logo (fetched from docs.nerf.studio) is a broken image: hide it.
        page.evaluate(
            "document.querySelectorAll('img').forEach(i => { if (!i.naturalWidth) i.style.visibility = 'hidden'; })"
        )
        time.sleep(0.3)  # let the panel repaint without the focus ring
        shot = page.screenshot()
    output_path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(shot).save(output_path, optimize=True)
    return output_path


def main() -> None:
    parser = argparse.ArgumentParser(description=save_viewer_screenshot.__doc__)
    parser.add_argument("--load-config", type=Path, required=True, help="config.yml of a trained ssnerf run")
    parser.add_argument("--output", type=Path, default=Path("docs/viewer_semantics.png"))
    parser.add_argument("--output-type", default="semantics")
    parser.add_argument("--camera-index", type=int, default=0, help="training camera whose pose the view takes")
    parser.add_argument("--max-res", type=int, default=512, help="the viewer's Max res (render size)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (1 is fastest on a shared 2-core box)")
    args = parser.parse_args()
    import torch

    torch.set_num_threads(args.threads)
    path = save_viewer_screenshot(args.load_config, args.output, args.output_type, args.camera_index, args.max_res)
    print(f"saved {path}")


if __name__ == "__main__":
    main()
