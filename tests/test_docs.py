"""The documentation: README.md and docs/ say what the code does today.

- Every command in a shell block of README.md and docs/*.md names a program that exists and only flags that program's
  `--help` lists (for the subcommand it names), so renaming a flag fails here wherever a page still uses the old name.
- Blocks marked runnable (```` ```bash runnable ````) run, top to bottom in a fresh folder per page, in their tiny
  form (`TINY`'s flags appended, as `tests/test_presets.py` runs presets with `--quick`).
- The results pages are what `scripts/results_pages.py` makes from the committed JSON, and adding a report works.
- The site builds with warnings as errors, and its API page lists every registry property.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import subprocess
import sys
from dataclasses import dataclass
from importlib.metadata import entry_points
from pathlib import Path
from typing import Dict, List, Optional, Tuple

import pytest
import yaml

from ssnerf_method.properties import REGISTRY

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
PAGES = [ROOT / "README.md", *sorted(DOCS.glob("*.md"))]
BIN = Path(sys.executable).parent
sys.path.insert(0, str(ROOT / "scripts"))

import results_pages  # noqa: E402

SHELLS = {"bash", "sh", "shell", "console"}
RUNNABLE = "runnable"
"""The word after the language in a block's info string (```` ```bash runnable ````) that makes the test run it."""
TINY: Dict[str, List[str]] = {
    "ssnerf-make-scene": ["--width", "32", "--height", "24", "--num-frames", "10", "--path-frames", "0"],
    "ns-train": ["--max-num-iterations", "2", "--vis", "tensorboard", "--machine.device-type", "cpu",
                 "--pipeline.datamanager.train-num-rays-per-batch", "64"],
    "ssnerf-demo": ["--max-num-iterations", "2", "--width", "32", "--height", "24", "--num-frames", "10"],
    "ssnerf-benchmark": ["--quick"],
    "ssnerf-study": ["--quick"],
    "ssnerf-label": ["--workers", "1"],
}
"""Flags appended to a runnable block's commands, per program: the tiny form of each (a 32x24 scene of 10 frames,
2 training steps, the CI-sized benchmark), which the test runs on a CPU in seconds."""
SHELL_WORDS = {"source", "cd", "export", "for", "do", "done", "then", "fi", "if", "else", "time", "echo", "set"}
"""Shell keywords and builtins a command line may hold; they take no flags to check."""
SUBCOMMAND = re.compile(r"^[a-z][a-z0-9-]*$")
"""A first positional word that may name a subcommand (`camera-path`, `ssnerf-lite`, `multitask`), as opposed to a
path (`my_scene`, `data/room_0`)."""
FLAG = re.compile(r"(?<![\w-])--[A-Za-z0-9][\w.\-]*")


@dataclass(frozen=True)
class Block:
    page: Path
    line: int
    info: str
    text: str

    @property
    def runnable(self) -> bool:
        return RUNNABLE in self.info.split()[1:]

    @property
    def where(self) -> str:
        return f"{self.page.relative_to(ROOT)}:{self.line}"


def shell_blocks(page: Path) -> List[Block]:
    """The fenced shell blocks of a Markdown page, with the line of their opening fence."""
    text = page.read_text()
    blocks = []
    for match in re.finditer(r"^(`{3,})([^\n`]*)\n(.*?)^\1[ \t]*$", text, re.M | re.S):
        info = match.group(2).strip()
        if info.split()[:1] and info.split()[0] in SHELLS:
            blocks.append(Block(page, text[: match.start()].count("\n") + 1, info, match.group(3)))
    return blocks


BLOCKS = [block for page in PAGES for block in shell_blocks(page)]


def command_lines(block: Block) -> List[Tuple[int, str]]:
    """Each logical line of a block (continuations joined) with its line number on the page."""
    lines, current, start = [], "", 0
    for number, line in enumerate(block.text.splitlines(), start=block.line + 1):
        start = start if current else number
        if line.rstrip().endswith("\\"):
            current += line.rstrip()[:-1] + " "
            continue
        lines.append((start, current + line))
        current = ""
    return [(number, line) for number, line in lines if line.strip()]


def simple_commands(line: str) -> List[List[str]]:
    """The simple commands of one shell line: split at `;`, `&&`, `||`, `|`, without `$(...)` substitutions, leading
    variable assignments and shell keywords; a `for` header is dropped."""
    line = re.sub(r"\$\([^)]*\)", "SUBSTITUTED", line)
    lexer = shlex.shlex(line, posix=True, punctuation_chars=";&|")
    lexer.whitespace_split, lexer.commenters = True, "#"
    commands: List[List[str]] = [[]]
    for token in lexer:
        if token and set(token) <= set(";&|"):
            commands.append([])
        else:
            commands[-1].append(token)
    result = []
    for tokens in commands:
        while tokens and (re.match(r"^\w+=", tokens[0]) or tokens[0] in ("do", "then", "else", "time", "!")):
            tokens = tokens[1:]
        if tokens and tokens[0] not in ("for", "done", "fi"):
            result.append(tokens)
    return result


CONSOLE_SCRIPTS = {point.name for point in entry_points(group="console_scripts")}


def program_of(tokens: List[str]) -> Tuple[Optional[List[str]], List[str], str]:
    """(the command line whose `--help` lists its flags, or None when there are none to check; the remaining
    arguments; a fault, or "")."""
    program = tokens[0].removeprefix(".venv/bin/")
    if program in ("python", "python3"):
        if tokens[1:2] == ["-m"] and tokens[2].split(".")[0] in ("ssnerf_method", "pytest"):
            return ["python", "-m", tokens[2]], tokens[3:], ""
        if tokens[1:2] == ["-m"] or tokens[1:2] == ["-c"]:
            return None, [], ""
        script = ROOT / tokens[1]
        if not script.is_file():
            return None, [], f"{tokens[1]}: no such script"
        return ["python", tokens[1]], tokens[2:], ""
    if program in CONSOLE_SCRIPTS:
        return [program], tokens[1:], ""
    if program in SHELL_WORDS or shutil.which(program) or (BIN / program).exists():
        return None, [], ""
    if "/" in program:
        return None, [], "" if (ROOT / program).is_file() else f"{program}: no such file"
    return None, [], f"{program}: no such program (not a console script, system command or shell builtin)"


def help_key(base: List[str], arguments: List[str]) -> List[str]:
    """The command line whose help lists the flags: `base` and the subcommand the arguments name, if any (for
    `ssnerf-study`, also the one its `--preset` names)."""
    if arguments and not arguments[0].startswith("-") and SUBCOMMAND.match(arguments[0]):
        return [*base, arguments[0]]
    if base == ["ssnerf-study"] and "--preset" in arguments:
        preset = ROOT / arguments[arguments.index("--preset") + 1]
        return [*base, yaml.safe_load(preset.read_text())["study"]]
    return base


@dataclass
class Use:
    where: str
    key: Tuple[str, ...]
    flags: List[str]


def collect_uses() -> Tuple[List[Use], List[str]]:
    """Every command on every page: the flags it uses by the help that must list them, and static faults."""
    uses, faults = [], []
    for block in BLOCKS:
        for number, line in command_lines(block):
            try:
                commands = simple_commands(line)
            except ValueError as error:
                faults.append(f"{block.page.relative_to(ROOT)}:{number}: cannot be parsed ({error})")
                continue
            for tokens in commands:
                where = f"{block.page.relative_to(ROOT)}:{number}: {' '.join(tokens)[:80]}"
                base, arguments, fault = program_of(tokens)
                if fault:
                    faults.append(f"{where}: {fault}")
                if base is None:
                    continue
                for index, argument in enumerate(arguments[:-1]):
                    if argument == "--preset" and not (ROOT / arguments[index + 1]).is_file():
                        faults.append(f"{where}: preset {arguments[index + 1]} does not exist")
                flags = [argument.split("=")[0] for argument in arguments if argument.startswith("--")]
                uses.append(Use(where, tuple(help_key(base, arguments)), flags))
    return uses, faults


@pytest.fixture(scope="module")
def help_texts(tmp_path_factory) -> Dict[str, Tuple[int, str]]:
    """`--help` of every command line the pages use, collected in one process (`tests/help_texts.py`)."""
    uses, _ = collect_uses()
    keys = sorted({use.key for use in uses})
    output = tmp_path_factory.mktemp("help") / "help.json"
    subprocess.run([sys.executable, str(ROOT / "tests" / "help_texts.py"), str(output)], input=json.dumps(keys),
                   text=True, check=True, timeout=600, env={**os.environ, "OMP_NUM_THREADS": "1"},
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return {key: tuple(value) for key, value in json.loads(output.read_text()).items()}


def test_the_pages_have_shell_blocks_and_the_readme_starts_with_the_two_commands() -> None:
    readme = (ROOT / "README.md").read_text()
    assert len(readme.splitlines()) <= 200
    first = shell_blocks(ROOT / "README.md")[0]
    assert [line.split("#")[0].strip() for _, line in command_lines(first)] == ["make demo", "make test"]
    assert any(block.runnable for block in BLOCKS) and len(BLOCKS) >= 20
    text = "".join(page.read_text() for page in PAGES)
    presets = sorted((ROOT / "configs").glob("*.yaml"))
    assert presets and all(f"--preset configs/{path.name}" in text for path in presets), "a page runs every preset"


def test_every_command_exists_and_every_flag_is_accepted(help_texts) -> None:
    uses, faults = collect_uses()
    for use in uses:
        status, text = help_texts[" ".join(use.key)]
        if status != 0:
            faults.append(f"{use.where}: `{' '.join(use.key)} --help` failed: {text[-300:]}")
            continue
        known = set(FLAG.findall(text)) | {"--help"}
        faults += [f"{use.where}: {' '.join(use.key)} has no flag {flag}" for flag in use.flags if flag not in known]
    assert not faults, "\n".join(faults)
    assert {"ns-train ssnerf-lite", "ns-render camera-path", "ssnerf-label"} <= set(help_texts)


def test_a_renamed_flag_is_caught(help_texts) -> None:
    """The check above can fail: a flag the help does not list is reported."""
    status, text = help_texts["ns-train ssnerf-lite"]
    known = set(FLAG.findall(text))
    assert status == 0 and "--pipeline.model.balancing.ratio" in known and "--pipeline.model.balance-ratio" not in known
    [tokens] = simple_commands("ns-train ssnerf-lite --data DATA --pipeline.model.balance-ratio 0.1  # comment")
    base, arguments, fault = program_of(tokens)
    assert help_key(base, arguments) == ["ns-train", "ssnerf-lite"] and not fault
    assert [argument for argument in arguments if argument.startswith("--")] == ["--data",
                                                                                  "--pipeline.model.balance-ratio"]
    assert program_of(["ssnerf-nonexistent"])[2] and program_of(["python", "scripts/missing.py"])[2]


def test_shell_lines_split_into_commands() -> None:
    line = 'CONFIG=$(ls a/*/config.yml) X=1 ns-eval --load-config $CONFIG; for p in a b; do ns-render x --y $p; done'
    assert simple_commands(line) == [["ns-eval", "--load-config", "$CONFIG"], ["ns-render", "x", "--y", "$p"]]
    assert simple_commands("make demo    # makes .venv") == [["make", "demo"]]


RUNNABLE_PAGES = sorted({block.page for block in BLOCKS if block.runnable})


@pytest.mark.parametrize("page", RUNNABLE_PAGES, ids=[page.name for page in RUNNABLE_PAGES])
def test_runnable_blocks_run_in_their_tiny_form(page: Path, tmp_path: Path) -> None:
    script = ["set -euo pipefail"]
    for block in (block for block in BLOCKS if block.page == page and block.runnable):
        for number, line in command_lines(block):
            commands = simple_commands(line)
            assert len(commands) == 1, f"{block.where}: a runnable block holds one command per line"
            tiny = TINY.get(commands[0][0], [])
            script.append(line.split(" #")[0].rstrip() + "".join(f" {shlex.quote(flag)}" for flag in tiny))
    result = subprocess.run(["bash", "-c", "\n".join(script)], cwd=tmp_path, capture_output=True, text=True,
                            timeout=900, env={**os.environ, "OMP_NUM_THREADS": "1",
                                              "PATH": f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}"})
    assert result.returncode == 0, "\n".join(script) + "\n" + (result.stdout + result.stderr)[-4000:]


def test_the_committed_results_pages_are_what_their_json_gives() -> None:
    assert results_pages.check() == []


def write_reports(folder: Path) -> None:
    """A benchmark's tables.json and a multi-task study's JSON, written by the plugin's own report code from made-up
    scores, with one figure."""
    from PIL import Image

    from ssnerf_method.experiments.report import write_report
    from ssnerf_method.experiments.studies import MultiTaskStudy, write_study_report
    from ssnerf_method.properties import OPTIONAL_PROPERTIES

    runs = ["nerf", *(f"ssnerf-{name}" for name in OPTIONAL_PROPERTIES), "ssnerf-all", "heuristic", "hybrid"]
    results = {scene: {run: {"psnr": 20.0 + index + 0.25, "semantics_miou": 0.5 + index / 100,
                             "edges_f1": 0.75, "normals_l1": 0.0312} for index, run in enumerate(runs)}
               for scene in ("scene_a", "scene_b")}
    write_report(folder, results, list(OPTIONAL_PROPERTIES), "ssnerf-lite", 1000)
    study = MultiTaskStudy(output=folder)
    scores = {scene: {run.name: {"shading_l1": 0.0425} for run in study.runs()} for scene in results}
    argv, sys.argv = sys.argv, ["ssnerf-study", "--preset", "configs/table4-multitask.yaml"]
    try:
        write_study_report(study, scores, {}, 60.0)
    finally:
        sys.argv = argv
    Image.new("RGB", (8, 4)).save(folder / "figure_scene_a.png")


def test_a_report_becomes_a_results_page(tmp_path: Path) -> None:
    docs, reports = tmp_path / "docs", tmp_path / "reports"
    reports.mkdir()
    write_reports(reports)
    assert results_pages.main(["--docs", str(docs), "build"]) == 0
    assert "No entries yet." in (docs / "results" / "index.md").read_text()
    with pytest.raises(SystemExit):  # a benchmark's tables.json records no command: the flags must say it
        results_pages.main(["--docs", str(docs), "add", str(reports / "tables.json"), "--machine", "2 cores"])
    assert results_pages.main(["--docs", str(docs), "add", str(reports), "--machine", "2 CPU cores", "--date",
                               "2026-12-03", "--command", "ssnerf-benchmark --preset configs/table1.yaml",
                               "--commit", "0123abc"]) == 0
    bench = (docs / "results" / "2026-12-03" / "benchmark" / "index.md").read_text()
    study = (docs / "results" / "2026-12-03" / "multitask" / "index.md").read_text()
    assert "`ssnerf-benchmark --preset configs/table1.yaml`" in bench and "2 CPU cores" in bench
    assert "| SS-NeRF, average | 0.5100 |" in bench  # semantics mIoU of the semantics model: from the JSON
    assert "| average | 20.25 |" in bench  # the NeRF's PSNR, Table 2-left
    assert "![figure_scene_a.png](figure_scene_a.png)" in bench and "figure_scene_a" not in study
    assert "`ssnerf-study --preset configs/table4-multitask.yaml`" in study and "| average | 0.0425 |" in study
    entry = docs / "results" / "2026-12-03"
    study_json = json.loads((reports / "study_multitask.json").read_text())
    sources = {name: json.loads((entry / name / "source.json").read_text()) for name in ("benchmark", "multitask")}
    assert sources["benchmark"]["commit"] == "0123abc" and sources["benchmark"]["machine"] == "2 CPU cores"
    assert sources["multitask"]["command"] == study_json["command"]  # what the report records wins over the flags
    assert sources["multitask"]["commit"] == (study_json["commit"] or "0123abc")
    index = (docs / "results" / "index.md").read_text()
    assert "2026-12-03/multitask/index\n2026-12-03/benchmark/index" in index
    assert results_pages.check(docs) == []
    with pytest.raises(SystemExit):  # the same study on the same day: refused unless named apart
        results_pages.main(["--docs", str(docs), "add", str(reports / "study_multitask.json"), "--machine", "2 CPU",
                            "--date", "2026-12-03", "--commit", "0123abc"])
    assert results_pages.main(["--docs", str(docs), "add", str(reports / "study_multitask.json"), "--machine",
                               "2 CPU", "--date", "2026-12-03", "--commit", "0123abc", "--entry", "multitask-b"]) == 0
    second = (entry / "multitask-b" / "index.md").read_text()
    assert second.startswith("# The multitask study (multitask-b), 2026-12-03") and (entry / "multitask").is_dir()
    assert results_pages.check(docs) == []
    page = docs / "results" / "2026-12-03" / "benchmark" / "index.md"
    page.write_text(page.read_text().replace("0.5100", "0.5200"))  # a number typed by hand
    assert results_pages.check(docs) == ["results/2026-12-03/benchmark/index.md: differs from its JSON"]
    assert results_pages.main(["--docs", str(docs), "check"]) == 1


def test_the_site_builds_without_warnings_and_lists_every_property(tmp_path: Path) -> None:
    from sphinx.cmd.build import build_main

    assert build_main(["-W", "--keep-going", "-q", "-b", "html", str(DOCS), str(tmp_path)]) == 0
    api = (tmp_path / "api.html").read_text()
    table = api.split('id="the-property-registry"')[1].split("</table>")[0]
    for spec in REGISTRY.values():
        assert f"<code class=\"docutils literal notranslate\"><span class=\"pre\">{spec.name}</span></code>" \
            f" ({spec.short})" in table, spec.name
    assert "SSNeRFModelConfig" in api and "regularisers" in api and "SparsityStudy" in api
    for page in ("getting-started", "own-data", "viewer", "method", "benchmark", "dataset-format", "troubleshooting",
                 "results/index", "development"):
        assert (tmp_path / f"{page}.html").is_file(), page


def test_tables_stored_as_mappings_become_tables_not_settings() -> None:
    """A study's per-scene results ({scene: {row: {column: value}}}) render as one table per scene."""
    tables = {"per_scene": {"scene_a": {"1 frame": {"SS-NeRF": 0.25, "Heuristic": 0.5}, "all": {"SS-NeRF": 0.75}}},
              "seed": 3}
    text = "\n\n".join(results_pages.render_tables(tables, {}, 2))
    assert "- seed: 3" in text and "{" not in text
    assert "## Per scene: scene_a" in text
    assert "| 1 frame | 0.2500 | 0.5000 |" in text and "| all | 0.7500 | – |" in text
