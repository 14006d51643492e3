"""Where the viewer listens: this machine only, unless the user asks for another host.

The Label panel writes into the user's dataset (strokes, answered clicks), so a viewer open to the network lets anyone
who can reach the port write there. nerfstudio binds its viewer to 0.0.0.0; our methods' configs say 127.0.0.1 for
`ns-train`, and `ns-viewer` (whose own viewer config replaces the run's) is brought to the same default when it loads
one of our pipelines. `--viewer.websocket-host 0.0.0.0` on either command still opens it to the network.
"""

from __future__ import annotations

import functools
import sys
from typing import Sequence

LOCAL_HOST = "127.0.0.1"
"""The address the viewer binds to unless the command line names one."""
ANY_HOST = "0.0.0.0"
"""nerfstudio's default: every network interface."""
HOST_FLAGS = ("--viewer.websocket-host", "--viewer.websocket_host")
"""The flags that name the viewer's host (tyro accepts either spelling)."""


def host_asked_for(argv: Sequence[str]) -> bool:
    """Whether the command line names the viewer's host."""
    return any(argument.split("=", 1)[0] in HOST_FLAGS for argument in argv)


def startup_line(host: str, port: int) -> str:
    """The viewer's address line, saying who can reach it."""
    if host == LOCAL_HOST:
        return (f"Viewer running locally at: http://{host}:{port} (this machine only; --viewer.websocket-host "
                f"{ANY_HOST} serves the network, and the Label panel writes into the dataset)")
    where = "every network interface" if host == ANY_HOST else host
    return (f"Viewer running at: http://{'localhost' if host == ANY_HOST else host}:{port} (listening on {where}: "
            "whoever reaches this port can paint labels into the dataset)")


def serve_locally_by_default() -> None:
    """Make nerfstudio's viewer bind to `LOCAL_HOST` where the command line named no host, and say so in its
    start-up line (installed once per process, by our pipeline before the viewer is made)."""
    from nerfstudio.viewer.viewer import Viewer

    if getattr(Viewer.__init__, "ssnerf_local_host", False):
        return
    original = Viewer.__init__

    @functools.wraps(original)
    def init(self, config, *args, **kwargs) -> None:
        if config.websocket_host == ANY_HOST and not host_asked_for(sys.argv[1:]):
            config.websocket_host = LOCAL_HOST
        original(self, config, *args, **kwargs)
        if not kwargs.get("share") and self.viewer_info:
            self.viewer_info[0] = startup_line(config.websocket_host, self.viser_server.get_port())

    init.ssnerf_local_host = True  # type: ignore[attr-defined]
    Viewer.__init__ = init  # type: ignore[method-assign]
