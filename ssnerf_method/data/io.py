"""Reading user images and writing datasets without ever leaving a half-written file or folder behind.

`read_image` turns every failure into one `DatasetInputError` naming the file and the fix; writes go through
`Staging` or `StagedOutputFolder` and atomic JSON, so an error midway leaves the user's folder as it was.
"""

from __future__ import annotations

import io
import json
import os
import shutil
import tempfile
from pathlib import Path
from types import TracebackType
from typing import Any, List, Optional, Tuple, Type

import cv2
import numpy as np

from ssnerf_method.atomic import atomic_file
from ssnerf_method.properties import LabelFileError


class DatasetInputError(LabelFileError):
    """An input dataset file or folder that cannot be used; the message names it and says what to do."""


def _missing(path: Path, what: str) -> DatasetInputError:
    if path.is_dir():
        return DatasetInputError(f"{path}: {what} listed in the dataset is a folder, not a file. Point its key at "
                                 "the file.")
    return DatasetInputError(f"{path}: {what} listed in the dataset does not exist. Add the file or remove the frame.")


def read_image(path: Path, what: str = "image") -> np.ndarray:
    """An image file as stored: (H, W) or (H, W, C) RGB(A), uint8 or uint16; `DatasetInputError` if unreadable."""
    if not path.is_file():
        raise _missing(path, what)
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None or image.size == 0:
        raise DatasetInputError(f"{path}: {what} cannot be decoded (corrupt or not an image). Re-export the file.")
    if image.ndim == 3 and image.shape[2] == 3:
        image = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    elif image.ndim == 3 and image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2RGBA)
    return image


def image_size(path: Path, what: str = "image") -> Tuple[int, int]:
    """(width, height) of an image file, read from its header where possible."""
    from PIL import Image, UnidentifiedImageError

    if not path.is_file():
        raise _missing(path, what)
    try:
        with Image.open(path) as image:
            return image.size
    except (OSError, UnidentifiedImageError) as err:
        raise DatasetInputError(f"{path}: {what} cannot be decoded ({err}). Re-export the file.") from err


def encode_png(image: np.ndarray) -> bytes:
    """PNG bytes of a uint8/uint16 (H, W) grey, (H, W, 2) grey+alpha, RGB or RGBA array."""
    if image.dtype not in (np.uint8, np.uint16):
        raise TypeError(f"PNG labels are uint8 or uint16, got {image.dtype}")
    if image.ndim == 3 and image.shape[2] == 2:  # OpenCV cannot write grey+alpha
        from PIL import Image

        buffer = io.BytesIO()
        Image.fromarray(image, mode="LA").save(buffer, format="PNG")
        return buffer.getvalue()
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_RGB2BGR if image.shape[2] == 3 else cv2.COLOR_RGBA2BGRA)
    ok, buffer = cv2.imencode(".png", image)
    if not ok:
        raise OSError("OpenCV could not encode the PNG")
    return buffer.tobytes()


def write_json_atomic(path: Path, data: Any) -> None:
    """Write `data` as indented JSON to `path`, whole or not at all (`atomic.atomic_file`)."""
    with atomic_file(path) as stream:
        json.dump(data, stream, indent=2)
        stream.write("\n")


def backup_once(path: Path) -> Path:
    """Copy `path` to `<path>.orig` unless that backup already exists (it then holds the true original)."""
    backup = path.with_name(path.name + ".orig")
    if not backup.exists():
        shutil.copy2(path, backup)
    return backup


class Staging:
    """Files written under `root` only when the whole job succeeded: `stage(relative)` gives a path in a hidden
    temporary folder, `commit()` moves them all into place; leaving the `with` block otherwise touches nothing."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self._folder: Optional[Path] = None
        self._staged: List[Path] = []

    def __enter__(self) -> "Staging":
        self.root.mkdir(parents=True, exist_ok=True)
        self._folder = Path(tempfile.mkdtemp(prefix=".ssnerf-staging-", dir=self.root))
        return self

    def stage(self, relative: Path) -> Path:
        assert self._folder is not None, "use Staging as a context manager"
        target = self._folder / relative
        target.parent.mkdir(parents=True, exist_ok=True)
        self._staged.append(Path(relative))
        return target

    def write_png(self, relative: Path, image: np.ndarray) -> None:
        self.stage(relative).write_bytes(encode_png(image))

    def commit(self) -> None:
        assert self._folder is not None, "use Staging as a context manager"
        for relative in self._staged:
            destination = self.root / relative
            destination.parent.mkdir(parents=True, exist_ok=True)
            os.replace(self._folder / relative, destination)
        self._staged = []

    def __exit__(
        self, kind: Optional[Type[BaseException]], error: Optional[BaseException], trace: Optional[TracebackType]
    ) -> None:
        if self._folder is not None:
            shutil.rmtree(self._folder, ignore_errors=True)
            self._folder = None


class StagedOutputFolder:
    """A new folder next to `destination` (missing or empty unless `overwrite`), renamed to it only on success (an
    old one moved aside until then); on an exception it and any parents it created are removed."""

    def __init__(self, destination: Path, overwrite: bool = False) -> None:
        self.destination = destination
        self.overwrite = overwrite
        self._folder: Optional[Path] = None
        self._created: Optional[Path] = None

    def __enter__(self) -> Path:
        destination = self.destination
        if destination.exists() and not destination.is_dir():
            raise DatasetInputError(f"{destination}: output exists and is not a folder. Pick another output folder.")
        if destination.is_dir() and any(destination.iterdir()) and not self.overwrite:
            raise DatasetInputError(
                f"{destination}: output folder exists and is not empty. Pass --overwrite to replace it, or pick "
                "another folder."
            )
        self._created = next((parent for parent in reversed(destination.parents) if not parent.exists()), None)
        destination.parent.mkdir(parents=True, exist_ok=True)
        self._folder = destination.parent / f".{destination.name}.partial-{os.getpid()}-{id(self):x}"
        self._folder.mkdir()
        return self._folder

    def __exit__(
        self, kind: Optional[Type[BaseException]], error: Optional[BaseException], trace: Optional[TracebackType]
    ) -> None:
        assert self._folder is not None, "use StagedOutputFolder as a context manager"
        folder, self._folder = self._folder, None
        if kind is None:
            try:
                self._replace_destination(folder)
                return
            except BaseException:
                self._discard(folder)
                raise
        self._discard(folder)

    def _replace_destination(self, folder: Path) -> None:
        """Rename `folder` to the destination, moving an existing destination aside until that succeeded."""
        old = self.destination.parent / f".{self.destination.name}.old-{os.getpid()}-{id(self):x}"
        moved_aside = self.destination.exists()
        if moved_aside:
            os.rename(self.destination, old)
        try:
            os.rename(folder, self.destination)
        except BaseException:
            if moved_aside:
                os.rename(old, self.destination)
            raise
        if moved_aside:
            shutil.rmtree(old, ignore_errors=True)

    def _discard(self, folder: Path) -> None:
        shutil.rmtree(folder, ignore_errors=True)
        if self._created is not None:
            shutil.rmtree(self._created, ignore_errors=True)
