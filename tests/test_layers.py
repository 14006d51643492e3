"""The package's dependencies point one way: each subpackage imports only from the layers below it, and no module
imports itself back through others. Read from the source (every import, at module level or inside a function)."""

from __future__ import annotations

import ast
from pathlib import Path
from typing import Dict, List, Set

import pytest

import ssnerf_method

ROOT = Path(ssnerf_method.__file__).parent

LAYERS: List[Set[str]] = [
    {"compat", "errors", "atomic", "label_makers"},  # numpy and OpenCV on images, nothing of ours above them
    {"properties"},  # the registry
    {"data", "metrics"},
    {"importers"},  # other datasets and annotation files (COCO, labelme) read into ours
    {"scene", "fields"},
    {"rendering", "viewer"},  # sampling runs the fields (their compiled form while training)
    {"model"},
    {"pipelines"},
    {"evaluation", "export", "label_tool"},  # ssnerf-label's engine: --depth-from renders with a trained model
    {"engine"},  # the trainer (atomic checkpoints, the last good one loaded)
    {"method_configs"},
    {"experiments"},
    {"cli"},  # every console script
]
"""Bottom to top. A subpackage (or top-level module) may import from its own unit and from lower layers only."""

LAYER_OF: Dict[str, int] = {unit: index for index, units in enumerate(LAYERS) for unit in units}


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def unit_of(module: str) -> str:
    """The top-level subpackage or module of `ssnerf_method.<unit>...`; "" for the package itself."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


def imports_of(path: Path) -> Set[str]:
    """Every `ssnerf_method` module `path` imports (a `from X import name` of a submodule counts as that module)."""
    found: Set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names if alias.name.startswith("ssnerf_method")}
        elif isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("ssnerf_method"):
            found.add(node.module)
            found |= {f"{node.module}.{alias.name}" for alias in node.names}
    return found


def graph() -> Dict[str, Set[str]]:
    modules = {module_name(path): path for path in ROOT.rglob("*.py")}
    return {name: {target for target in imports_of(path) if target in modules and target != name}
            for name, path in modules.items()}


def test_every_unit_has_a_layer():
    units = {unit_of(module) for module in graph()} - {""}
    assert units - set(LAYER_OF) == set(), "a new subpackage needs a place in LAYERS"
    assert set(LAYER_OF) - units == set(), "LAYERS names a subpackage that no longer exists"


def test_imports_point_down():
    wrong = []
    for module, targets in graph().items():
        source = unit_of(module)
        for target in targets:
            dest = unit_of(target)
            if source == dest or source == "":
                continue
            if dest == "" or LAYER_OF[dest] >= LAYER_OF[source]:
                wrong.append(f"{module} -> {target}")
    assert wrong == []


def test_data_reads_no_model_code():
    """The issue's rule in its own words: data/ imports nothing from fields/, model/ or scene/."""
    offending = {target for module, targets in graph().items() if unit_of(module) == "data"
                 for target in targets if unit_of(target) in ("fields", "model", "scene")}
    assert offending == set()


def test_no_module_cycle():
    edges = graph()
    state: Dict[str, int] = {}
    stack: List[str] = []

    def visit(module: str) -> None:
        state[module] = 1
        stack.append(module)
        for target in sorted(edges[module]):
            if state.get(target) == 1:
                pytest.fail("import cycle: " + " -> ".join(stack[stack.index(target):] + [target]))
            if target not in state:
                visit(target)
        stack.pop()
        state[module] = 2

    for module in sorted(edges):
        if module not in state:
            visit(module)


def test_the_checker_sees_a_backward_import(tmp_path):
    """The layer rule would catch data importing the field (what `add_pose_metadata` once did)."""
    probe = tmp_path / "probe.py"
    probe.write_text("from ssnerf_method.fields.ssnerf_field import SSNeRFField\n")
    targets = imports_of(probe)
    assert "ssnerf_method.fields.ssnerf_field" in targets
    assert LAYER_OF[unit_of("ssnerf_method.fields.ssnerf_field")] > LAYER_OF["data"]
