"""Errors a user can fix, and how they reach the user: one line per fault on stderr and exit status 1, no traceback.

Our own console scripts catch `UserError` at their entrypoint. nerfstudio's (`ns-train`, `ns-eval`, `ns-render`)
are not ours, so importing this package installs a `sys.excepthook` that prints an uncaught `UserError` the same way
and leaves every other exception to the previous hook. `SSNERF_TRACEBACK=1` shows the full traceback instead, for
debugging.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from types import TracebackType
from typing import NoReturn, Optional, Type

TRACEBACK_VARIABLE = "SSNERF_TRACEBACK"
"""Environment variable: set to 1 to see the traceback of a `UserError` instead of its one-line report."""


class UserError(Exception):
    """Bad input or a failed run that the user can fix. Each line of the message names the file (or frame, loss, step)
    and says what to do; nothing else is worth showing them."""


def _program() -> str:
    return Path(sys.argv[0]).name if sys.argv and sys.argv[0] else "ssnerf"


def report(error: UserError, program: Optional[str] = None) -> None:
    """Print `error` to stderr, each line prefixed with the program's name (as `sys.exit(message)` would), in red on
    a terminal as nerfstudio shows a bad config, never wrapped."""
    from rich.console import Console
    from rich.markup import escape

    console = Console(stderr=True, soft_wrap=True, highlight=False)
    name = program or _program()
    for line in str(error).splitlines() or [type(error).__name__]:
        console.print(f"[bold red]{escape(name)}:[/bold red] {escape(line)}")


def exit_with(error: UserError, program: Optional[str] = None) -> NoReturn:
    """Report `error` and exit with status 1; with `SSNERF_TRACEBACK=1` re-raise it instead."""
    if os.environ.get(TRACEBACK_VARIABLE, "") not in ("", "0"):
        raise error
    report(error, program)
    sys.exit(1)


def install_error_hook() -> None:
    """Make an uncaught `UserError` print as `report` does (exit status stays 1); idempotent."""
    previous = sys.excepthook
    if getattr(previous, "ssnerf_hook", False):
        return

    def hook(kind: Type[BaseException], error: BaseException, trace: Optional[TracebackType]) -> None:
        if isinstance(error, UserError) and os.environ.get(TRACEBACK_VARIABLE, "") in ("", "0"):
            report(error)
            return
        previous(kind, error, trace)

    hook.ssnerf_hook = True  # type: ignore[attr-defined]
    sys.excepthook = hook
