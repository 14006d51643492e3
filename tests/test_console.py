"""A quiet console: our commands' `--help`, a short `ns-train`, a tiny `ssnerf-demo`, and `ns-eval` and `ns-render`
on a trained model show none of nerfstudio 1.1.5's known third-party deprecation warnings (`compat.KNOWN_WARNINGS`,
installed at interpreter start by the package's `.pth` hook), and the warnings are silenced only where they come
from."""

from __future__ import annotations

import json
import os
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
DEPRECATION = re.compile(r"\b(FutureWarning|DeprecationWarning)\b")
"""A deprecation warning of any library, as Python prints it."""


def known_warning_in(text: str) -> list:
    return [message for _, message, _ in KNOWN_WARNINGS if re.search(message, text)]


HELP_OF_EACH = r"""
import importlib, json, os, sys, tempfile
scripts = json.loads(sys.argv[1])
entrypoints = {name: getattr(importlib.import_module(target.split(":")[0]), target.split(":")[1])
               for name, target in scripts.items()}  # warnings at import time go to this process's stderr
results = {}
for name, entrypoint in entrypoints.items():
    out, err = tempfile.TemporaryFile("w+"), tempfile.TemporaryFile("w+")
    pid = os.fork()
    if pid == 0:  # the command alone, as its console script runs it, its output in the two files
        os.dup2(out.fileno(), 1)
        os.dup2(err.fileno(), 2)
        sys.argv = [name, "--help"]
        try:
            code = entrypoint() or 0
        except SystemExit as exit:
            code = exit.code if isinstance(exit.code, int) else 1
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    _, status = os.waitpid(pid, 0)
    out.seek(0)
    err.seek(0)
    results[name] = [os.waitstatus_to_exitcode(status), out.read(), err.read()]
print(json.dumps(results))
"""
"""Every command's `--help`, each in a process forked once the commands' modules are imported: the torch and
nerfstudio imports are paid once, not once per command (nine fresh interpreters took 111 s of CI on 2 cores)."""


def test_help_of_every_command_we_ship_is_quiet() -> None:
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    assert "ssnerf-check" in scripts and len(scripts) >= 8
    result = subprocess.run([sys.executable, "-c", HELP_OF_EACH, json.dumps(scripts)], capture_output=True,
                            text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]
    assert not known_warning_in(result.stderr) and not DEPRECATION.search(result.stderr), result.stderr
    helps = json.loads(result.stdout)
    assert set(helps) == set(scripts)
    for name, (code, out, err) in helps.items():
        assert code == 0, (name, err)
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
    assert not DEPRECATION.search(result.stderr + result.stdout), result.stderr  # e.g. the trainer's GradScaler


def test_the_demo_is_quiet(tmp_path: Path) -> None:
    """`make demo`'s command, in a tiny form: training, reloading, scoring and rendering print no deprecation warning
    (without the filters it prints torch.jit's and torch.cuda.amp's FutureWarnings)."""
    result = subprocess.run(
        [BIN / "ssnerf-demo", "--output-dir", str(tmp_path / "demo"), "--method", "ssnerf-lite",
         "--max-num-iterations", "5", "--width", "48", "--height", "36", "--num-frames", "10"],
        capture_output=True, text=True, timeout=600, env={**os.environ, "OMP_NUM_THREADS": "1"},
    )
    output = result.stdout + result.stderr
    assert result.returncode == 0, output[-3000:]
    assert (tmp_path / "demo" / "metrics.json").is_file()
    assert not DEPRECATION.search(output), output
    assert not known_warning_in(output), output


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


def test_the_warnings_hook_is_installed_and_light() -> None:
    """`ssnerf_method_warnings.pth` (installed by the build backend, `build_hooks/`) runs at every interpreter start:
    the filters are in place before anything is imported, and it imports neither torch nor the package."""
    probe = ("import sys, warnings; "
             "print(sum(f[0] == 'ignore' and f[1] is not None and f[1].pattern.startswith('`torch') "
             "for f in warnings.filters), 'torch' in sys.modules, 'ssnerf_method' in sys.modules)")
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60, check=True)
    known_torch = sum(message.startswith("`torch") for _, message, _ in KNOWN_WARNINGS)
    assert result.stdout.split() == [str(known_torch), "False", "False"], result.stdout + result.stderr


def test_ns_eval_and_ns_render_print_no_deprecation_warning(trained_scene, tmp_path: Path) -> None:
    """nerfstudio's commands import nerfstudio (and with it torch's and torchmetrics' deprecated names) before they
    find the plugin: only the `.pth` hook silences those."""
    scene, config = trained_scene
    commands = {
        "ns-eval": ["--load-config", str(config), "--output-path", str(tmp_path / "eval.json")],
        "ns-render": ["camera-path", "--load-config", str(config), "--camera-path-filename",
                      str(scene / "camera_paths" / "fly_through.json"), "--output-path", str(tmp_path / "rgb.mp4"),
                      "--rendered-output-names", "rgb", "--output-format", "images"],
    }
    running = {name: subprocess.Popen([BIN / name, *args], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                      env={**os.environ, "OMP_NUM_THREADS": "1"})
               for name, args in commands.items()}
    for name, process in running.items():
        output, _ = process.communicate(timeout=600)
        assert process.returncode == 0, (name, output[-3000:])
        assert not DEPRECATION.search(output), (name, output)
    assert (tmp_path / "eval.json").is_file() and any((tmp_path / "rgb").glob("*.jpg"))
