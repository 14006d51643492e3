"""Does the environment `make demo` made run every command the README's own-data and labelling blocks show?

`.ci/run` calls it right after the demo's install step (`make env demo-system`), before the test extras and their
apt packages arrive, so that a command that needs something only the tests install fails CI. It imports the modules
the documented commands load late (open3d: `ns-export`, `ssnerf-export-points`; pycolmap: `ssnerf-process`), checks
the binaries they run (ffmpeg: `ns-render`'s videos) and runs each documented command's `--help` (its program and
subcommand, the rest of the line left out). One line per fault; exit status 1 if there is any.

    .venv/bin/python scripts/check_environment.py [--readme README.md]
"""

from __future__ import annotations

import argparse
import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path
from typing import List, Tuple

SECTIONS = ("Quick start on your own data", "Label your own scene")
"""The README's sections whose bash blocks a user with their own capture runs."""
LATE_IMPORTS = ("open3d", "pycolmap")
"""Modules the documented commands import only when they run (a missing system library shows only then)."""
PROGRAMS = ("ffmpeg",)
"""Binaries the documented commands run (`ns-render` writes its videos with ffmpeg)."""
BLOCK = re.compile(r"```bash\n(.*?)```", re.S)


def documented_commands(readme: Path) -> List[List[str]]:
    """The program and subcommand words of every command in `SECTIONS`' bash blocks: a line's words up to its first
    option (`-`), path (`/`, `.`) or placeholder (`my_scene`: a `_`), without the `source` of the environment."""
    text, commands = readme.read_text(), []
    for title in SECTIONS:
        start = text.index(f"## {title}")
        end = text.find("\n## ", start + 1)
        for block in BLOCK.findall(text[start:end if end > 0 else None]):
            for line in block.replace("\\\n", " ").splitlines():
                words = shlex.split(line, comments=True)
                if not words or words[0] == "source":
                    continue
                head = [words[0]]
                for word in words[1:]:
                    if word.startswith("-") or "/" in word or "_" in word or "." in word:
                        break
                    head.append(word)
                if head not in commands:
                    commands.append(head)
    return commands


def check(readme: Path) -> List[str]:
    faults = []
    for module in LATE_IMPORTS:
        done = subprocess.run([sys.executable, "-c", f"import {module}"], capture_output=True, text=True)
        if done.returncode:
            faults.append(f"import {module}: {last_line(done.stderr)}")
    for binary in PROGRAMS:
        if shutil.which(binary) is None:
            faults.append(f"{binary}: not on the PATH (make demo installs it with apt-get)")
    bin_dir = Path(sys.executable).parent
    for command in documented_commands(readme):
        program = bin_dir / command[0]
        if not program.exists():
            faults.append(f"{' '.join(command)}: no such program in {bin_dir}")
            continue
        done = subprocess.run([str(program), *command[1:], "--help"], capture_output=True, text=True,
                              env={**os.environ, "COLUMNS": "120"})
        if done.returncode:
            why = last_line(done.stderr or done.stdout)
            faults.append(f"{' '.join(command)} --help: exit {done.returncode}, {why}")
    return faults


def last_line(text: str) -> str:
    lines = [line.strip() for line in text.strip().splitlines() if line.strip()]
    return lines[-1][:200] if lines else "(no output)"


def main(argv: Tuple[str, ...] = ()) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--readme", type=Path, default=Path(__file__).resolve().parent.parent / "README.md")
    readme = parser.parse_args(list(argv)).readme
    faults = check(readme)
    for fault in faults:
        print(f"check_environment: {fault}", file=sys.stderr)
    if not faults:
        print(f"check_environment: {len(documented_commands(readme))} documented commands, "
              f"{', '.join(LATE_IMPORTS + PROGRAMS)} work in {Path(sys.executable).parent.parent}")
    return 1 if faults else 0


if __name__ == "__main__":
    sys.exit(main(tuple(sys.argv[1:])))
