"""The registry is the one place: a sixth property added as one registry row (plus its label maker, the behaviour it
needs) is generated in the scene, labelled by `ssnerf-label`, trained, evaluated, rendered as a viewer output and
reported in the benchmark's Table 1, with no other file touched.

The test edits a copy of the package exactly as the README's worked example does and runs it in a fresh Python, so
whatever any module derives from the registry at import time is derived with the new row.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

import ssnerf_method

MAKER = '''
class NormalTurn(LabelMaker):
    """How fast the surface turns: the normal's change to the next pixel right and down, |dn| / sqrt(2) in [0, 1]."""

    reads = ("normals",)
    help = "How fast the surface turns, from the frame's normals."

    def make(self, frame, options):
        from ssnerf_method.label_makers.encoding import to_uint8
        from ssnerf_method.label_makers.makers import Skip, with_alpha

        if frame.normals is None:
            raise Skip("no normals")
        normals, turn = frame.normals, np.zeros(frame.normals.shape[:2])
        turn[:-1] = np.maximum(turn[:-1], np.linalg.norm(normals[1:] - normals[:-1], axis=-1))
        turn[:, :-1] = np.maximum(turn[:, :-1], np.linalg.norm(normals[:, 1:] - normals[:, :-1], axis=-1))
        value = np.clip(turn / np.sqrt(2.0), 0.0, 1.0)
        return with_alpha(to_uint8(value), np.isfinite(value))

    def describe(self, options):
        return "normal change to the next pixel, |dn| / sqrt(2)"


'''

ROW = '''        PropertySpec(name="curvature", short="CV", kind=ScalarKind("sigmoid"), file_key="curvature_file_path",
                     branch="nv", loss="l1", weight=0.4, metric="l1", colormap="gray", label_maker=NormalTurn()),
'''

SCRIPT = textwrap.dedent('''
    import json, sys
    from pathlib import Path

    sys.meta_path[:] = [finder for finder in sys.meta_path if "__editable__" not in repr(finder)
                        and "__editable__" not in str(getattr(finder, "__module__", ""))]
    sys.path.insert(0, sys.argv[1])
    out = Path(sys.argv[2])

    import torch
    torch.set_num_threads(1)
    import ssnerf_method
    assert Path(ssnerf_method.__file__).parent == Path(sys.argv[1]) / "ssnerf_method", ssnerf_method.__file__

    from nerfstudio.utils.eval_utils import eval_setup
    from ssnerf_method.data.transforms import load_transforms
    from ssnerf_method.experiments.benchmark import BenchmarkConfig, run
    from ssnerf_method.label_tool.label_dataset import LabelDatasetConfig, label_dataset
    from ssnerf_method.scene.make_scene import MakeSceneConfig, make_scene

    scene = make_scene(MakeSceneConfig(output_dir=out / "scene", width=40, height=30, num_frames=10,
                                       trajectory="walkthrough", path_frames=0)).parent
    frame = json.loads((scene / "transforms.json").read_text())["frames"][0]
    facts = {"scene_key": frame.get("curvature_file_path")}
    facts["scene_file"] = (scene / frame["curvature_file_path"]).is_file()

    report = label_dataset(LabelDatasetConfig(data=scene, output="relabelled.json", relabel=True, workers=1),
                           load_transforms(scene))
    facts["label_outcomes"] = dict(report.outcomes.get("curvature", {}))

    results = run(BenchmarkConfig(quick=True, output=out / "bench", scenes=(scene,), properties=("curvature",),
                                  all_properties_model=False))
    facts["rows"] = {row: sorted(metrics) for row, metrics in results["scene"].items()}
    facts["curvature_l1"] = results["scene"]["ssnerf-curvature"]["curvature_l1"]
    facts["table1"] = json.loads((out / "bench" / "tables.json").read_text())["table1"]
    facts["report_has_column"] = "CV l1" in (out / "bench" / "report.md").read_text()

    config = next((out / "bench" / "runs").rglob("ssnerf-curvature/**/config.yml"))
    _, pipeline, _, _ = eval_setup(config, test_mode="test")
    outputs = pipeline.model.get_outputs_for_camera(pipeline.datamanager.eval_dataset.cameras[0:1])
    facts["outputs"] = {key: list(value.shape) for key, value in outputs.items() if key.startswith("curvature")}
    facts["checkpoints"] = sorted(path.name for path in (config.parent / "nerfstudio_models").iterdir())
    print("FACTS " + json.dumps(facts))
''')


def package_with_new_property(root: Path) -> Path:
    """A copy of the installed package whose `properties.py` has the maker and the row added, and nothing else."""
    package = root / "ssnerf_method"
    shutil.copytree(Path(ssnerf_method.__file__).parent, package, ignore=shutil.ignore_patterns("__pycache__"))
    registry = package / "properties.py"
    text = registry.read_text()
    assert text.count("REGISTRY: Dict[str, PropertySpec] = {") == 1 and text.count("\n    )\n}\n") == 1
    text = text.replace("REGISTRY: Dict[str, PropertySpec] = {", MAKER + "REGISTRY: Dict[str, PropertySpec] = {")
    registry.write_text(text.replace("\n    )\n}\n", "\n" + ROW + "    )\n}\n"))
    return root


@pytest.mark.filterwarnings("ignore")
def test_a_property_added_by_one_registry_row_runs_end_to_end(tmp_path: Path) -> None:
    root = package_with_new_property(tmp_path / "pkg")
    script = tmp_path / "run.py"
    script.write_text(SCRIPT)
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": ""}
    done = subprocess.run([sys.executable, str(script), str(root), str(tmp_path / "out")], capture_output=True,
                          text=True, env=env, timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    facts = json.loads(done.stdout.split("FACTS ", 1)[1])

    assert facts["scene_key"] == "curvature/frame_00000.png" and facts["scene_file"]  # the generator made it
    assert facts["label_outcomes"] == {"labelled": 10}  # ssnerf-label made it
    assert set(facts["rows"]) == {"nerf", "ssnerf-curvature", "heuristic", "hybrid", "nearest"}
    assert "curvature_l1" in facts["rows"]["heuristic"] and "curvature_l1" in facts["rows"]["hybrid"]
    assert facts["checkpoints"] == ["step-000000029.ckpt"]  # trained the quick benchmark's 30 steps
    assert 0.0 < facts["curvature_l1"] < 1.0  # and evaluated
    assert facts["report_has_column"] and all("curvature" in row for row in facts["table1"])
    assert facts["outputs"]["curvature"] == [30, 40, 3]  # the viewer's colour-mapped channel
