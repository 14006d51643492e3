"""A quiet console: our commands' `--help` and a short `ns-train` show none of nerfstudio 1.1.5's known torch
deprecation warnings (`compat.KNOWN_WARNINGS`), and the warnings are silenced only where they come from."""

from __future__ import annotations

import re
import subprocess
import sys
import warnings
from pathlib import Path

import tomllib

from ssnerf_method.compat import KNOWN_WARNINGS

from conftest import write_tiny_dataset

ROOT = Path(__file__).parents[1]
BIN = Path(sys.executable).parent


def known_warning_in(text: str) -> list:
    return [message for _, message, _ in KNOWN_WARNINGS if re.search(message, text)]


def test_help_of_every_command_we_ship_is_quiet() -> None:
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    assert "ssnerf-check" in scripts and len(scripts) >= 8
    running = {name: subprocess.Popen([BIN / name, "--help"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
               for name in scripts}
    for name, process in running.items():
        out, err = process.communicate(timeout=300)
        assert process.returncode == 0, (name, err)
        assert "usage" in out.lower(), name
        assert not known_warning_in(err), (name, err)


def test_short_ns_train_is_quiet(tmp_path: Path) -> None:
    """The per-batch `Cameras` indexing warning would print on every step; it is silenced from the plugin's import."""
    write_tiny_dataset(tmp_path / "data")
    result = subprocess.run(
        [BIN / "ns-train", "ssnerf-lite", "--data", str(tmp_path / "data"), "--vis", "tensorboard", "--output-dir",
         str(tmp_path / "outputs"), "--max-num-iterations", "3", "--machine.device-type", "cpu",
         "--pipeline.datamanager.train-num-rays-per-batch", "64"],
        capture_output=True, text=True, timeout=600,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    assert not re.search(KNOWN_WARNINGS[2][1], result.stderr + result.stdout)


def test_only_those_warnings_are_silenced() -> None:
    """The same message from another module, and another message from nerfstudio's cameras, still show."""
    import ssnerf_method  # noqa: F401  (installs the filters)

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("default")
        from ssnerf_method.compat import quiet_known_warnings

        quiet_known_warnings()
        warnings.warn_explicit("Using a non-tuple sequence for multidimensional indexing is deprecated", UserWarning,
                               "elsewhere.py", 1, module="my_package.module")
        warnings.warn_explicit("something else", UserWarning, "cameras.py", 1, module="nerfstudio.cameras.cameras")
        warnings.warn_explicit("Using a non-tuple sequence for multidimensional indexing is deprecated", UserWarning,
                               "cameras.py", 2, module="nerfstudio.cameras.cameras")
    assert [str(warning.message) for warning in caught] == [
        "Using a non-tuple sequence for multidimensional indexing is deprecated", "something else"]
