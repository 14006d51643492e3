"""Run presets (`configs/`, `--preset`): every file parses into its command's options in the --quick form, typed flags
win over the file, the documentation's commands name every preset, and a bad preset ends in one line naming the file."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml

from ssnerf_method.cli.study import STUDIES, parse
from ssnerf_method.experiments import presets
from ssnerf_method.experiments.benchmark import BenchmarkConfig

REPO = Path(__file__).resolve().parents[1]
PRESETS = sorted((REPO / "configs").glob("*.yaml"))


def load(path: Path, *typed: str) -> Any:
    """What `ssnerf-benchmark` or `ssnerf-study` would run for `--preset path` followed by `typed`."""
    if presets.STUDY_KEY in yaml.safe_load(path.read_text()):
        return parse(["--preset", str(path), *typed])
    return presets.cli(BenchmarkConfig, "ssnerf-benchmark", ["--preset", str(path), *typed])


def same(value: Any, wanted: Any) -> bool:
    """A parsed option against the preset's YAML value (tuples for lists, paths for strings, nested groups)."""
    if dataclasses.is_dataclass(value) and isinstance(wanted, dict):
        return all(same(getattr(value, key.replace("-", "_")), inner) for key, inner in wanted.items())
    if isinstance(wanted, list):
        return list(value) == wanted
    if isinstance(value, Path):
        return value == Path(wanted)
    return value == wanted


def test_configs_holds_the_presets() -> None:
    assert len(PRESETS) >= 9  # Table 1 (two models), Tables 2-6, auto-labelling, sparsity, the cluster example
    assert {path.stem.split("-")[0] for path in PRESETS} >= {"table1", "table2", "table3", "table4", "table5",
                                                              "table6", "autolabel", "sparsity", "cluster"}


@pytest.mark.parametrize("path", PRESETS, ids=[path.name for path in PRESETS])
def test_every_preset_parses_in_quick_form_and_the_readme_runs_it(path: Path, tmp_path: Path) -> None:
    data = yaml.safe_load(path.read_text())
    config = load(path, "--quick", "--output", str(tmp_path))
    study = data.pop(presets.STUDY_KEY, None)
    assert type(config) is (STUDIES[study] if study else BenchmarkConfig)
    assert config.quick and config.output == tmp_path  # typed flags after the preset win
    for key, value in data.items():
        if key != "output":
            assert same(getattr(config, key), value), key
    pages = "".join(page.read_text() for page in [REPO / "README.md", *(REPO / "docs").glob("*.md")])
    assert f"--preset configs/{path.name}" in pages, "the documentation runs every preset"


def test_typed_flags_override_the_preset_and_the_study_can_be_typed(tmp_path: Path) -> None:
    preset = REPO / "configs" / "table4-multitask.yaml"
    config = parse(["multitask", "--preset", str(preset), "--steps", "7", "--target", "edges"])
    assert (config.steps, config.target, config.others) == (7, "edges", ("semantics", "normals", "keypoints", "edges"))
    assert load(REPO / "configs" / "table1.yaml").steps == 3000
    assert load(REPO / "configs" / "table1.yaml", "--steps", "30").steps == 30


@pytest.mark.parametrize("text, message", [
    ("stepz: 10\n", "`stepz` is not an option of BenchmarkConfig"),
    ("steps: many\n", "Error parsing --steps"),
    ("properties: [semantics, colour]\n", "invalid choice 'colour'"),
    ("- steps\n", "a preset is a mapping"),
    ("steps: [1\n", "not valid YAML"),
    ("hybrid:\n  widht: 3\n", "`hybrid.widht` is not an option"),
    ("study: multitask\n", "Run it with ssnerf-study"),
])
def test_a_bad_benchmark_preset_names_the_file(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(presets.PresetError, match=message) as raised:
        presets.cli(BenchmarkConfig, "ssnerf-benchmark", ["--preset", str(path)])
    assert str(raised.value).startswith(str(path))


def test_a_bad_study_preset_names_the_file(tmp_path: Path) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text("target: shading\n")
    with pytest.raises(presets.PresetError, match="needs `study:`"):
        parse(["--preset", str(path)])
    path.write_text("study: multitask\n")
    with pytest.raises(presets.PresetError, match="`rgb` was typed"):
        parse(["rgb", "--preset", str(path)])
    with pytest.raises(presets.PresetError, match="preset file not found"):
        parse(["--preset", str(tmp_path / "missing.yaml")])


def test_the_console_script_says_one_line(tmp_path: Path) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text("stepz: 10\n")
    done = subprocess.run([sys.executable, "-m", "ssnerf_method.cli.benchmark", "--preset", str(path)],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 1
    assert done.stderr.strip().splitlines()[-1].startswith(f"ssnerf-benchmark: {path}: `stepz` is not an option")
