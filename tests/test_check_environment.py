"""`scripts/check_environment.py`, which `.ci/run` runs in the demo's environment: it reads the README's own-data
commands and reports each one that does not run, and each late import that fails."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "scripts"))

import check_environment  # noqa: E402


def test_the_readme_own_data_commands_are_read_with_their_subcommands() -> None:
    commands = check_environment.documented_commands(ROOT / "README.md")
    assert ["ns-train", "ssnerf-lite"] in commands and ["ssnerf-export-points"] in commands
    assert ["ssnerf-process", "images"] in commands and ["ns-render", "interpolate"] in commands
    assert all(not word.startswith("-") and "/" not in word for command in commands for word in command)
    assert ["source"] not in commands and len(commands) == len({tuple(command) for command in commands})


def test_a_command_or_an_import_that_fails_is_one_line_each(tmp_path: Path, monkeypatch) -> None:
    readme = tmp_path / "README.md"
    readme.write_text("# x\n\n## Quick start on your own data\n\n```bash\nssnerf-check my_scene   # works\n"
                      "ssnerf-no-such-tool my_scene\n```\n\n## Label your own scene\n\n```bash\n"
                      "ssnerf-check my_scene --annotations a.json\n```\n\n## Next\n\n```bash\nignored-tool\n```\n")
    assert check_environment.documented_commands(readme) == [["ssnerf-check"], ["ssnerf-no-such-tool"]]
    monkeypatch.setattr(check_environment, "LATE_IMPORTS", ("json", "no_such_module_for_the_check"))
    monkeypatch.setattr(check_environment, "PROGRAMS", ("sh", "no-such-binary-for-the-check"))
    faults = check_environment.check(readme)
    assert len(faults) == 3, faults
    assert faults[0].startswith("import no_such_module_for_the_check: ") and "No module named" in faults[0]
    assert faults[1].startswith("no-such-binary-for-the-check: not on the PATH")
    assert faults[2].startswith("ssnerf-no-such-tool: no such program")
    assert check_environment.main(("--readme", str(readme))) == 1


@pytest.mark.parametrize("section", check_environment.SECTIONS)
def test_the_sections_it_reads_are_in_the_readme(section: str) -> None:
    assert f"## {section}\n" in (ROOT / "README.md").read_text()
