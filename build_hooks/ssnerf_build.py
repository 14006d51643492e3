"""The build backend: setuptools', plus `ssnerf_method_warnings.pth` at the root of every wheel it builds.

A `.pth` file in site-packages is run by Python's `site` module at every interpreter start, before `ns-eval` or
`ns-render` import nerfstudio, which is the only way to silence the third-party warnings those imports print
(`ssnerf_method/compat.py`). setuptools installs no such file from an editable install (`pip install -e .`, as
`make env` does: its editable wheels leave out data files), so this backend adds it to the wheel itself, regular or
editable, and lists it in the wheel's RECORD: pip installs it into site-packages and `pip uninstall` removes it.
"""

from __future__ import annotations

import base64
import hashlib
import zipfile
from pathlib import Path
from typing import Optional

from setuptools import build_meta as _setuptools
from setuptools.build_meta import *  # noqa: F401,F403  (every other hook is setuptools')

PTH = Path(__file__).with_name("ssnerf_method_warnings.pth")


def _add_pth(wheel: Path) -> None:
    """Rewrite `wheel` with `PTH` at its root and a RECORD line for it."""
    data = PTH.read_bytes()
    digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
    entry = f"{PTH.name},sha256={digest},{len(data)}\n"
    with zipfile.ZipFile(wheel) as source:
        items = [(info, source.read(info)) for info in source.infolist()]
    with zipfile.ZipFile(wheel, "w", zipfile.ZIP_DEFLATED) as target:
        target.writestr(PTH.name, data)
        for info, content in items:
            if info.filename.endswith(".dist-info/RECORD"):
                content = entry.encode() + content
            target.writestr(info, content)


def build_wheel(wheel_directory: str, config_settings: Optional[dict] = None,
                metadata_directory: Optional[str] = None) -> str:
    name = _setuptools.build_wheel(wheel_directory, config_settings, metadata_directory)
    _add_pth(Path(wheel_directory) / name)
    return name


def build_editable(wheel_directory: str, config_settings: Optional[dict] = None,
                   metadata_directory: Optional[str] = None) -> str:
    name = _setuptools.build_editable(wheel_directory, config_settings, metadata_directory)
    _add_pth(Path(wheel_directory) / name)
    return name
