"""Write, as JSON into the file named by the first argument, the `--help` output and exit status of each command line
read from stdin (a JSON list of argv lists), all in this one process so that torch and nerfstudio are imported once.
`tests/test_docs.py` checks every flag on the documentation's pages against these texts.

A command line is a console script and its subcommands (`["ns-render", "camera-path"]`), `["python", "-m", MODULE,
...]`, or `["python", "SCRIPT.py", ...]`; `--help` is appended here.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import runpy
import sys
from importlib.metadata import entry_points
from typing import List, Tuple

os.environ["COLUMNS"] = "400"  # one line per option: no flag name is wrapped
SCRIPTS = {point.name: point for point in entry_points(group="console_scripts")}


def help_of(argv: List[str]) -> Tuple[int, str]:
    """Run `argv --help` in this process; its exit status and everything it printed."""
    printed, status, saved = io.StringIO(), 0, sys.argv
    with contextlib.redirect_stdout(printed), contextlib.redirect_stderr(printed):
        try:
            if argv[0] == "python" and argv[1] == "-m":
                sys.argv = [argv[2], *argv[3:], "--help"]
                runpy.run_module(argv[2], run_name="__main__", alter_sys=True)
            elif argv[0] == "python":
                sys.argv = [*argv[1:], "--help"]
                runpy.run_path(argv[1], run_name="__main__")
            else:
                sys.argv = [*argv, "--help"]
                SCRIPTS[argv[0]].load()()
        except SystemExit as done:
            status = done.code if isinstance(done.code, int) else int(done.code is not None)
        except BaseException as error:  # noqa: BLE001 (reported to the test, which fails on it)
            status = 1
            printed.write(f"{type(error).__name__}: {error}")
    sys.argv = saved
    return status, printed.getvalue()


if __name__ == "__main__":
    output, commands = sys.argv[1], json.loads(sys.stdin.read())
    texts = {" ".join(argv): help_of(argv) for argv in commands}
    with open(output, "w") as file:
        json.dump(texts, file)
