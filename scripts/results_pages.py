"""The documentation's results pages, generated from the JSON that `ssnerf-benchmark` and `ssnerf-study` write.

    python scripts/results_pages.py add REPORT [REPORT ...] --machine "2 CPU cores, no GPU" [--date YYYY-MM-DD]
    python scripts/results_pages.py build     # every page again, from docs/results/
    python scripts/results_pages.py check     # exit status 1 when a page differs from what its JSON gives

A report is a benchmark's `tables.json`, a study's `study_<name>.json`, or a folder holding them. `add` copies each
into `docs/results/<date>/<name>/` with the report's figures (`figure_*.png` of that study or of its scenes) and a
`source.json` saying where it came from (command, commit, machine, date), then rebuilds the pages: one `index.md` per
entry and `docs/results/index.md`, newest first. Every number on those pages is read from the entry's JSON; nothing is
typed by hand, and `tests/test_docs.py` fails when a committed page differs from what this script makes.
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import re
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Dict, List, Optional, Sequence

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ssnerf_method.errors import UserError, exit_with  # noqa: E402

DOCS = ROOT / "docs"
RESULTS = "results"
SOURCE = "source.json"
MAX_FIGURE_BYTES = 3_000_000
"""A larger figure is left out of an entry (the repository keeps entries small)."""
BENCHMARK_FILE = "tables.json"
STUDY_PREFIX = "study_"


def column_titles() -> Dict[str, str]:
    """JSON column key -> title, from the registry (as the reports title them): `semantics` -> `SL miou ↑`,
    `edges_f1` -> `ED f1 ↑`, `nerf` -> `NeRF`, `ssnerf-edges` -> `SS-NeRF-ED`."""
    from ssnerf_method.metrics import METRICS
    from ssnerf_method.properties import REGISTRY

    titles = {"nerf": "NeRF", "ssnerf-all": "SS-NeRF, all properties"}
    for spec in REGISTRY.values():
        titles[f"ssnerf-{spec.name}"] = f"SS-NeRF-{spec.short}"
        for index, (key, higher) in enumerate(METRICS[spec.metric].reported):
            key_in_json = spec.name if index == 0 else spec.metric_prefix + key
            titles[key_in_json] = f"{spec.short} {key} {'↑' if higher else '↓'}"
    return titles


def number(value: Any) -> str:
    """A cell: floats with 2 decimals from 10 up (PSNR, degrees), else 4; empty for missing values."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "–"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.2f}" if abs(value) >= 10 else f"{value:.4f}"
    if isinstance(value, (list, dict)):
        return "`" + json.dumps(value) + "`"
    return str(value)


def title_of(key: str, titles: Dict[str, str]) -> str:
    """A column's title: the registry's for a known key, also as the last word of a composite key."""
    if key in titles:
        return titles[key]
    head, _, last = key.rpartition(" ")
    return f"{head} {titles[last]}" if head and last in titles else key


def is_rows(value: Any) -> bool:
    """A table as the reports store it: a list of row mappings, each named by "row"."""
    return isinstance(value, list) and bool(value) and all(isinstance(row, dict) and "row" in row for row in value)


def markdown_table(rows: List[Dict[str, Any]], titles: Dict[str, str]) -> str:
    columns: List[str] = []
    for row in rows:
        columns += [key for key in row if key != "row" and key not in columns]
    lines = ["| | " + " | ".join(title_of(key, titles) for key in columns) + " |", "|---|" + "---|" * len(columns)]
    lines += ["| " + str(row["row"]) + " | " + " | ".join(number(row.get(key)) for key in columns) + " |"
              for row in rows]
    return "\n".join(lines)


def heading(key: str) -> str:
    """`table2_left` -> `Table 2 left`, `table4_shading_f1` -> `Table 4 shading f1`, `sparsity` -> `Sparsity`."""
    words = key.replace("_", " ")
    if words.startswith("table") and words[5:6].isdigit():
        words = "Table " + words[5:]
    return words[:1].upper() + words[1:]


def is_grid(value: Any) -> bool:
    """A table stored as a mapping: row name -> {column: scalar}."""
    return (isinstance(value, dict) and bool(value) and all(
        isinstance(row, dict) and row and not any(isinstance(cell, (dict, list)) for cell in row.values())
        for row in value.values()))


def grid_rows(grid: Dict[str, Dict[str, Any]]) -> List[Dict[str, Any]]:
    return [{"row": name, **columns} for name, columns in grid.items()]


def is_table_group(value: Any) -> bool:
    """Tables under names (e.g. per scene): row lists, or mappings of row mappings."""
    return isinstance(value, dict) and bool(value) and (any(map(is_rows, value.values()))
                                                        or all(map(is_grid, value.values())))


def render_tables(tables: Dict[str, Any], titles: Dict[str, str], level: int) -> List[str]:
    """Every table of a report's JSON, in its order: row lists (or mappings of row mappings) as tables, groups of
    them under subheadings, other values as a list of settings first."""
    settings = [f"- {key}: {number(value)}" for key, value in tables.items()
                if not is_rows(value) and not is_grid(value) and not is_table_group(value)]
    parts = ["Settings:", "\n".join(settings)] if settings else []
    for key, value in tables.items():
        if is_rows(value):
            parts += [f"{'#' * level} {heading(key)}", markdown_table(value, titles)]
        elif is_grid(value):
            parts += [f"{'#' * level} {heading(key)}", markdown_table(grid_rows(value), titles)]
        elif is_table_group(value) and all(map(is_grid, value.values())):
            for name, grid in value.items():
                parts += [f"{'#' * level} {heading(key)}: {name}", markdown_table(grid_rows(grid), titles)]
        elif is_table_group(value):
            parts += [f"{'#' * level} {heading(key)}", *render_tables(value, titles, level + 1)]
    return parts


def spacing_table(spacing: Dict[str, Dict[str, Any]]) -> str:
    """The benchmark's test-to-training-view distances per scene."""
    lines = ["| scene | test views | median distance to the nearest training view (m) | median angle (°) |",
             "|---|---|---|---|"]
    lines += [f"| {scene} | {number(values.get('test_views'))} | {number(values.get('median_m'))} | "
              f"{number(values.get('median_deg'))} |" for scene, values in spacing.items()]
    return "\n".join(lines)


@dataclass
class Entry:
    """One committed report: its folder under docs/results/, its JSON and where it came from."""

    folder: Path
    report: Dict[str, Any]
    source: Dict[str, Any]

    @property
    def kind(self) -> str:
        return self.source["kind"]

    @property
    def title(self) -> str:
        what = ("Benchmark: Table 1 and Table 2 (left)" if self.kind == "benchmark"
                else f"The {self.source['name']} study")
        if self.source.get("entry"):
            what += f" ({self.source['entry']})"
        return f"{what}, {self.source['date']}"

    def page(self, titles: Dict[str, str]) -> str:
        """The entry's page, from its JSON only."""
        report, source = self.report, self.source
        quick = " (`--quick`: tiny scenes and models, a test of the pipeline, not a measurement)" if report.get(
            "quick") else ""
        drop = report.get("lr_drop")
        lines = [f"# {self.title}", "",
                 "Generated by `scripts/results_pages.py` from "
                 f"[`{source['file']}`]({source['file']}) (where it came from: [`{SOURCE}`]({SOURCE})).", "",
                 f"- Command: `{source['command']}`",
                 f"- Commit: `{source['commit']}`",
                 f"- Machine: {source['machine']}",
                 f"- Method: `{report.get('method')}`, {report.get('steps')} steps per model"
                 + (f", learning rates ×0.1 after {number(drop)} of them" if drop is not None else "") + quick]
        if report.get("wall_clock_seconds") is not None:
            lines.append(f"- Wall-clock time of the command: {report['wall_clock_seconds'] / 60.0:.1f} min"
                         " (runs it found finished are reused, not retrained)")
        trained = [run.get("train_seconds") for scene in report.get("runs", {}).values() if isinstance(scene, dict)
                   for run in scene.values() if isinstance(run, dict) and run.get("train_seconds") is not None]
        if trained:
            lines.append(f"- Training time of the {len(trained)} runs, added up: {sum(trained) / 60.0:.1f} min")
        scenes = list(report.get("results", {}))
        if scenes:
            lines.append("- Scenes: " + ", ".join(f"`{scene}`" for scene in scenes))
        parts = ["\n".join(lines)]
        if self.kind == "benchmark":
            if report.get("spacing"):
                parts += ["## How far the test views are from the training views", spacing_table(report["spacing"])]
            parts += ["## Table 1: scene properties", markdown_table(report["table1"], titles),
                      "## Table 2 (left): RGB PSNR", markdown_table(report["table2_left"], titles)]
        else:
            parts += render_tables(report.get("tables", {}), titles, 2)
        figures = sorted(path.name for path in self.folder.glob("figure_*.png"))
        if figures:
            parts += ["## Figures", "\n\n".join(f"![{name}]({name})" for name in figures)]
        return "\n\n".join(parts) + "\n"


def load_entries(docs: Path) -> List[Entry]:
    """Every entry under `docs/results/`, newest first (then by name)."""
    entries = []
    for source_path in (docs / RESULTS).glob(f"*/*/{SOURCE}"):
        source = json.loads(source_path.read_text())
        report = json.loads((source_path.parent / source["file"]).read_text())
        entries.append(Entry(source_path.parent, report, source))
    return sorted(entries, key=lambda entry: (entry.source["date"], entry.source["name"]), reverse=True)


def pages(docs: Path) -> Dict[Path, str]:
    """Every generated page (path -> text): one per entry and the index."""
    titles = column_titles()
    entries = load_entries(docs)
    result = {entry.folder / "index.md": entry.page(titles) for entry in entries}
    index = ["# Results", "",
             "Measured results, one page per report, newest first. Each page is generated from the JSON file that "
             "`ssnerf-benchmark` or `ssnerf-study` wrote, committed beside it under `docs/results/<date>/` with the "
             "command, the commit and the machine it came from; no number here is typed by hand. To add one, see "
             "[adding a results entry](../development.md#adding-a-results-entry). What changed for a user, and "
             "when, is in `CHANGELOG.md`."]
    if entries:
        index += ["", "```{toctree}", ":maxdepth: 1", "",
                  *(entry.folder.relative_to(docs / RESULTS).as_posix() + "/index" for entry in entries), "```"]
    else:
        index += ["", "No entries yet."]
    result[docs / RESULTS / "index.md"] = "\n".join(index) + "\n"
    return result


def build(docs: Path = DOCS) -> List[Path]:
    """Write every page; returns the paths written."""
    written = []
    for path, text in pages(docs).items():
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
        written.append(path)
    return written


def check(docs: Path = DOCS) -> List[str]:
    """The pages that are missing or differ from what their JSON gives, and generated pages no entry makes."""
    wanted = pages(docs)
    faults = [f"{path.relative_to(docs)}: {'differs from' if path.is_file() else 'missing, but'} its JSON"
              for path, text in wanted.items() if not path.is_file() or path.read_text() != text]
    faults += [f"{path.relative_to(docs)}: a page without an entry ({SOURCE} is missing)"
               for path in (docs / RESULTS).glob("*/*/index.md") if path not in wanted]
    return faults


def reports_in(path: Path) -> List[Path]:
    """The report JSON files `path` names: itself, or those in the folder."""
    if path.is_dir():
        found = sorted([*path.glob(BENCHMARK_FILE), *path.glob(f"{STUDY_PREFIX}*.json")])
        if not found:
            raise UserError(f"{path}: holds no {BENCHMARK_FILE} or {STUDY_PREFIX}<name>.json. Name a report folder "
                            "of ssnerf-benchmark or ssnerf-study (their --output), or one of those files.")
        return found
    if not path.is_file():
        raise UserError(f"{path}: does not exist. Name a report folder or a report's JSON file.")
    if path.name != BENCHMARK_FILE and not (path.name.startswith(STUDY_PREFIX) and path.suffix == ".json"):
        raise UserError(f"{path}: is not a report's JSON ({BENCHMARK_FILE} or {STUDY_PREFIX}<name>.json).")
    return [path]


def add(path: Path, machine: str, date: Optional[str] = None, command: Optional[str] = None,
        commit: Optional[str] = None, overwrite: bool = False, docs: Path = DOCS,
        extra_figures: Sequence[Path] = (), entry: Optional[str] = None) -> Path:
    """Copy one report JSON and its figures (a benchmark's `figure_<scene>.png`, a study's `figure_<name>*.png`, and
    `extra_figures`) into a new entry; returns the entry's folder. Pages are not rebuilt."""
    try:
        report = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as error:
        raise UserError(f"{path}: cannot be read as JSON ({error}). Name the JSON file the command wrote.") from None
    kind = "benchmark" if path.name == BENCHMARK_FILE else "study"
    name = "benchmark" if kind == "benchmark" else path.stem[len(STUDY_PREFIX):]
    needed = ("table1", "table2_left") if kind == "benchmark" else ("tables",)
    missing = [key for key in needed if key not in report]
    if missing:
        raise UserError(f"{path}: has no {', '.join(missing)}: not a report of this plugin's {kind}.")
    command = report.get("command") or command  # what the report records wins; the flags fill what it lacks
    commit = report.get("commit") or commit
    if not command or not commit:
        raise UserError(f"{path}: records no {'command' if not command else 'commit'} (a benchmark's tables.json "
                        "records neither). Pass --command 'THE COMMAND THAT WROTE IT' and --commit HASH.")
    if not machine.strip():
        raise UserError("--machine is empty: say what it ran on (cores, GPU), e.g. --machine '2 CPU cores, no GPU'.")
    date = date or datetime.datetime.fromtimestamp(path.stat().st_mtime, datetime.timezone.utc).date().isoformat()
    try:
        datetime.date.fromisoformat(date)
    except ValueError:
        raise UserError(f"--date {date}: not a date. Give it as YYYY-MM-DD.") from None
    if entry is not None and not re.fullmatch(r"[a-z0-9]+(-[a-z0-9]+)*", entry):
        raise UserError(f"--entry {entry!r}: not a folder name. Give lower-case words joined by hyphens, e.g. "
                        "'propagation-clicks'.")
    folder = docs / RESULTS / date / (entry or name)
    if folder.exists() and not overwrite:
        raise UserError(f"{folder}: exists. Pass --overwrite to replace that entry, or --entry to add another one "
                        "of the same day.")
    scenes = list(report.get("results", {}))
    patterns = [f"figure_{scene}.png" for scene in scenes] if kind == "benchmark" else [f"figure_{name}*.png"]
    figures = {figure for pattern in patterns for figure in path.parent.glob(pattern)} | set(extra_figures)
    absent = [str(figure) for figure in extra_figures if not figure.is_file()]
    if absent:
        raise UserError(f"--figures {' '.join(absent)}: no such file. Name PNG files the report wrote.")
    large = sorted(figure.name for figure in figures if figure.stat().st_size > MAX_FIGURE_BYTES)
    if folder.exists():
        shutil.rmtree(folder)
    folder.mkdir(parents=True)
    shutil.copyfile(path, folder / path.name)
    for figure in sorted(figures):
        if figure.name not in large:
            shutil.copyfile(figure, folder / figure.name)
    source = {"kind": kind, "name": name, "file": path.name, "date": date, "command": command, "commit": commit,
              "machine": machine.strip(), "figures_left_out": large, **({"entry": entry} if entry else {})}
    (folder / SOURCE).write_text(json.dumps(source, indent=2) + "\n")
    return folder


def main(argv: Optional[Sequence[str]] = None) -> int:
    parser = argparse.ArgumentParser(prog="results_pages.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("--docs", type=Path, default=DOCS, help="the documentation folder (default: docs/)")
    commands = parser.add_subparsers(dest="command", required=True)
    adding = commands.add_parser("add", help="copy reports into docs/results/ and rebuild the pages")
    adding.add_argument("reports", type=Path, nargs="+", help="tables.json, study_<name>.json, or their folder")
    adding.add_argument("--machine", required=True, help="what it ran on, e.g. '2 CPU cores, no GPU'")
    adding.add_argument("--date", help="the entry's date, YYYY-MM-DD (default: the day the JSON was written)")
    adding.add_argument("--command", dest="report_command", help="the command that wrote the report "
                        "(a study's JSON records it; a benchmark's tables.json does not)")
    adding.add_argument("--commit", help="the commit it ran at (as --command)")
    adding.add_argument("--overwrite", action="store_true", help="replace an entry of the same date and name")
    adding.add_argument("--entry", help="the entry's folder name, for a second report of the same study on one day "
                        "(default: the report's name)")
    adding.add_argument("--figures", type=Path, nargs="+", default=[], help="more figures of the report to show "
                        "(by default: a benchmark's figure_<scene>.png, a study's figure_<name>*.png)")
    commands.add_parser("build", help="write every page from docs/results/")
    commands.add_parser("check", help="exit status 1 when a page differs from what its JSON gives")
    args = parser.parse_args(argv)
    try:
        if args.command == "add":
            files = [report for path in args.reports for report in reports_in(path)]
            for report in files:
                folder = add(report, args.machine, args.date, args.report_command, args.commit, args.overwrite,
                             args.docs, args.figures, args.entry)
                print(f"added {folder}")
        if args.command in ("add", "build"):
            for path in build(args.docs):
                print(f"wrote {path}")
            return 0
        faults = check(args.docs)
        for fault in faults:
            print(fault)
        if faults:
            print("Run `python scripts/results_pages.py build` and commit the pages.")
        return 1 if faults else 0
    except UserError as error:
        exit_with(error, "results_pages.py")


if __name__ == "__main__":
    sys.exit(main())
