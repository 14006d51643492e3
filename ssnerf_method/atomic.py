"""Files that are whole or absent: a result, report or checkpoint is never half-written.

`atomic_file` writes to a temporary file beside the destination, flushes it to disk (fsync), renames it over the
destination and syncs the folder, so a process killed mid-write, or a machine that loses power, leaves either the old
file or the new one, never a truncated file that a later run would take for a finished one.

The temporary file is `.<name>.<host>-<pid>.<random>.partial`: hidden, matched by no pattern a reader looks for
(`step-*.ckpt`, `metrics.json`), and naming its writer, so that `remove_stale_partials` can delete the ones a killed
writer left behind without touching a write still in progress.
"""

from __future__ import annotations

import contextlib
import os
import secrets
import socket
from pathlib import Path
from typing import IO, Any, Iterator, List, Literal, Optional, Tuple

PARTIAL_SUFFIX = ".partial"
"""Ending of a temporary file that `atomic_file` has not renamed into place (yet)."""


def _host() -> str:
    return socket.gethostname().replace(".", "_")


def _writer_of(partial: Path) -> Optional[Tuple[str, int]]:
    """(host, pid) of the process that started writing `partial`, or None if the name is not one of ours."""
    parts = partial.name.rsplit(".", 3)
    if len(parts) != 4 or parts[3] != PARTIAL_SUFFIX[1:] or "-" not in parts[1]:
        return None
    host, pid = parts[1].rsplit("-", 1)
    return (host, int(pid)) if pid.isdigit() else None


def _running(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    return True


def _sync_folder(folder: Path) -> None:
    """Make a rename in `folder` durable (a no-op where the platform cannot open or sync a folder)."""
    try:
        handle = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(handle)
    except OSError:
        pass
    finally:
        os.close(handle)


@contextlib.contextmanager
def atomic_file(path: Path, mode: Literal["w", "wb"] = "w") -> Iterator[IO[Any]]:
    """A stream (text in UTF-8, or binary) to write `path` through: it becomes `path` only when the `with` block ends
    normally; an exception deletes it and leaves `path` as it was. Missing parent folders are created."""
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.name}.{_host()}-{os.getpid()}.{secrets.token_hex(4)}{PARTIAL_SUFFIX}")
    handle = os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)  # the umask applies, as to any file
    try:
        with os.fdopen(handle, mode, encoding=None if "b" in mode else "utf-8") as stream:
            yield stream
            stream.flush()
            os.fsync(stream.fileno())
        os.replace(temporary, path)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
    _sync_folder(path.parent)


def write_text_atomic(path: Path, text: str) -> None:
    """Write `text` to `path` through `atomic_file`."""
    with atomic_file(path) as stream:
        stream.write(text)


def write_bytes_atomic(path: Path, data: bytes) -> None:
    """Write `data` to `path` through `atomic_file`."""
    with atomic_file(path, "wb") as stream:
        stream.write(data)


def save_torch_atomic(obj: Any, path: Path) -> None:
    """`torch.save(obj)` to `path` through `atomic_file` (checkpoints, trained networks' weights)."""
    import torch  # (here: nothing else in this module needs torch)

    with atomic_file(path, "wb") as stream:
        torch.save(obj, stream)


def remove_stale_partials(folder: Path) -> List[Path]:
    """Delete the temporary files in `folder` whose writer, a process on this host, is no longer running (a killed
    write); returns them. Another host's are kept: whether their writer lives cannot be told from here."""
    removed = []
    for partial in sorted(folder.glob(f".*{PARTIAL_SUFFIX}")):
        writer = _writer_of(partial)
        if writer is not None and writer[0] == _host() and not _running(writer[1]):
            partial.unlink(missing_ok=True)
            removed.append(partial)
    return removed
