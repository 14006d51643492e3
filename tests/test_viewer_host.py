"""The viewer of our models listens on this machine only unless the command line names another host.

`ns-viewer` is run as its own code runs it (`eval_setup`, then its own viewer config, whose host is nerfstudio's
0.0.0.0, then `Viewer`); the socket the viewer's server really listens on is read from the kernel's table.
"""

from __future__ import annotations

import sys
import threading
from pathlib import Path
from typing import Set

import pytest

from ssnerf_method.method_configs import ssnerf_config, ssnerf_lite_config
from ssnerf_method.viewer.host import LOCAL_HOST, host_asked_for

from browser_driver import free_port


def listening(port: int) -> Set[str]:
    """The IPv4 addresses a socket listens on at `port` (from /proc/net/tcp: hex little-endian address, state 0A)."""
    addresses = set()
    for line in Path("/proc/net/tcp").read_text().splitlines()[1:]:
        local, state = line.split()[1], line.split()[3]
        address, hex_port = local.split(":")
        if int(hex_port, 16) == port and state == "0A":
            addresses.add(".".join(str(int(address[i : i + 2], 16)) for i in (6, 4, 2, 0)))
    return addresses


def start_ns_viewer(config_path: Path, argv, monkeypatch):
    """What `ns-viewer --load-config CONFIG [argv]` does up to its endless loop: the viewer of a loaded run."""
    from nerfstudio.scripts.viewer.run_viewer import RunViewer
    from nerfstudio.utils.eval_utils import eval_setup
    from nerfstudio.viewer.viewer import Viewer

    monkeypatch.setattr(sys, "argv", ["ns-viewer", "--load-config", str(config_path), *argv])
    config, pipeline, _, _ = eval_setup(config_path, eval_num_rays_per_chunk=None, test_mode="test")
    run_viewer = RunViewer(load_config=config_path)
    if argv:
        run_viewer.viewer.websocket_host = argv[argv.index("--viewer.websocket-host") + 1]
    config.viewer = run_viewer.viewer.as_viewer_config()  # (0.0.0.0, nerfstudio's default, unless argv named one)
    config.viewer.websocket_port = free_port()
    return Viewer(config.viewer, log_filename=config.get_base_dir() / "viewer_log_filename.txt",
                  datapath=pipeline.datamanager.get_datapath(), pipeline=pipeline, share=False,
                  train_lock=threading.Lock())


@pytest.mark.filterwarnings("ignore")
@pytest.mark.parametrize("argv, expected", [([], LOCAL_HOST), (["--viewer.websocket-host", "0.0.0.0"], "0.0.0.0")])
def test_ns_viewer_on_our_model_listens_on_this_machine_unless_told(trained_scene, monkeypatch, argv,
                                                                     expected) -> None:
    _, config_path = trained_scene
    viewer = start_ns_viewer(config_path, argv, monkeypatch)
    try:
        port = viewer.viser_server.get_port()
        assert listening(port) == {expected}
        line = viewer.viewer_info[0]
        assert f":{port}" in line
        assert ("this machine only" in line) == (expected == LOCAL_HOST)
        assert ("every network interface" in line) == (expected == "0.0.0.0")
    finally:
        viewer.viser_server.stop()


def test_ns_train_of_our_methods_serves_locally_and_the_flag_is_recognised() -> None:
    assert ssnerf_config.viewer.websocket_host == ssnerf_lite_config.viewer.websocket_host == LOCAL_HOST
    assert host_asked_for(["--viewer.websocket-host", "0.0.0.0"])
    assert host_asked_for(["--viewer.websocket_host=10.0.0.2"])
    assert not host_asked_for(["--viewer.websocket-port", "7007", "--data", "websocket-host"])
