"""Run presets: `ssnerf-benchmark --preset configs/table1.yaml`, `ssnerf-study --preset configs/table4-multitask.yaml`.

A preset is a YAML mapping of the command's options (nested ones as mappings, e.g. `hybrid: {steps: 3000}`), plus,
for `ssnerf-study`, `study:` naming the subcommand. Its flags go before the typed ones, so typed flags win.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import sys
from pathlib import Path
from typing import Any, Dict, List, Optional, Sequence, Tuple, Type, TypeVar

import tyro
import yaml

from ssnerf_method.errors import UserError

PRESET_FLAG = "--preset"
STUDY_KEY = "study"
"""The preset key naming `ssnerf-study`'s subcommand."""

Config = TypeVar("Config")


class PresetError(UserError, ValueError):
    """A preset file that cannot be used; the message names the file and the fix."""


def preset_path(args: Sequence[str]) -> Optional[Path]:
    """The `--preset PATH` (or `--preset=PATH`) among `args`, the last one if given twice."""
    found = None
    for index, arg in enumerate(args):
        if arg == PRESET_FLAG and index + 1 < len(args):
            found = Path(args[index + 1])
        elif arg.startswith(PRESET_FLAG + "="):
            found = Path(arg.split("=", 1)[1])
    return found


def read_preset(path: Path) -> Dict[str, Any]:
    """The preset's mapping, or one line naming the file and what is wrong with it."""
    if not path.is_file():
        raise PresetError(f"{path}: preset file not found. Give the path of a YAML file, e.g. configs/table1.yaml.")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as err:
        raise PresetError(f"{path}: not valid YAML ({str(err).splitlines()[0]}). Fix the file's syntax.") from err
    if not isinstance(data, dict):
        raise PresetError(f"{path}: a preset is a mapping of option names to values (`steps: 2000`), got "
                          f"{type(data).__name__}. Rewrite it as `name: value` lines.")
    return data


def _check_keys(path: Path, cls: Type, data: Dict[str, Any], prefix: str = "") -> None:
    """Every key of `data` names an option of `cls` (a mapping, a nested option group)."""
    defaults = cls()
    names = {field.name for field in dataclasses.fields(cls)}
    for key, value in data.items():
        name = str(key).replace("-", "_")
        if name not in names:
            raise PresetError(f"{path}: `{prefix}{key}` is not an option of {cls.__name__} (options: "
                              f"{', '.join(sorted(names))}). Remove it or fix its name.")
        if isinstance(value, dict):
            inner = getattr(defaults, name)
            if not dataclasses.is_dataclass(inner):
                raise PresetError(f"{path}: `{prefix}{key}` takes a value, not a mapping. Give it one value.")
            _check_keys(path, type(inner), value, f"{prefix}{key}.")


def _check_values(path: Path, target: Any, flags: List[str], prog: str) -> None:
    """The preset's flags parse on their own; else one line naming the file and tyro's complaint."""
    captured = io.StringIO()
    try:
        with contextlib.redirect_stderr(captured), contextlib.redirect_stdout(captured):
            tyro.cli(target, args=flags, prog=prog)
    except SystemExit as err:
        lines = [line.strip(" │╭╮╰╯─-") for line in captured.getvalue().splitlines()]  # rich's box, or its ASCII
        title = next((index for index, line in enumerate(lines) if line), 0)  # the box's title, e.g. "Value error"
        start = next((index for index, line in enumerate(lines) if index > title
                      and any(word in line.lower() for word in ("error parsing", "invalid", "unrecognized"))), None)
        if start is None:
            reason = "its values do not parse"
        else:
            end = next((index for index in range(start, len(lines)) if not lines[index]), len(lines))
            reason = " ".join(lines[start:end])
        raise PresetError(f"{path}: {reason} (as flags: {' '.join(flags)}). Fix that value.") from err


def to_flags(data: Dict[str, Any], prefix: str = "") -> List[str]:
    """A preset mapping as flags: `--name value`, `--flag`/`--no-flag`, a list as its values, `--name.inner value`."""
    flags: List[str] = []
    for key, value in data.items():
        name = prefix + str(key).replace("_", "-")
        if isinstance(value, dict):
            flags += to_flags(value, name + ".")
        elif isinstance(value, bool):
            flags.append(f"--{name}" if value else f"--{prefix}no-{str(key).replace('_', '-')}")
        elif isinstance(value, (list, tuple)):
            flags += [f"--{name}", *(str(item) for item in value)]
        elif value is not None:
            flags += [f"--{name}", str(value)]
    return flags


def cli(cls: Type[Config], prog: str, args: Optional[Sequence[str]] = None) -> Config:
    """`tyro.cli(cls)` with the flags of `--preset` (if given) placed before the typed ones."""
    args = list(sys.argv[1:] if args is None else args)
    path = preset_path(args)
    if path is None:
        return tyro.cli(cls, args=args, prog=prog)
    data = read_preset(path)
    if STUDY_KEY in data:
        raise PresetError(f"{path}: a study preset (it names `study: {data[STUDY_KEY]}`). Run it with ssnerf-study.")
    _check_keys(path, cls, data)
    flags = to_flags(data)
    _check_values(path, cls, flags, prog)
    return tyro.cli(cls, args=[*flags, *args], prog=prog)


def study_cli(studies: Dict[str, Type], union: Any, prog: str, args: Optional[Sequence[str]] = None) -> Any:
    """`tyro.cli(union)` where a `--preset` gives the subcommand (`study:`) and its flags; a typed one must match."""
    args = list(sys.argv[1:] if args is None else args)
    path = preset_path(args)
    if path is None:
        return tyro.cli(union, args=args, prog=prog)
    data = dict(read_preset(path))
    study = data.pop(STUDY_KEY, None)
    if study not in studies:
        raise PresetError(f"{path}: a study preset needs `study:` naming one of {', '.join(studies)} (got {study}). "
                          "Add that line.")
    typed: Tuple[str, ...] = tuple(args[:1]) if args and args[0] in studies else ()
    if typed and typed[0] != study:
        raise PresetError(f"{path}: is a preset of `ssnerf-study {study}`, but `{typed[0]}` was typed. Drop one.")
    _check_keys(path, studies[study], data)
    flags = [study, *to_flags(data)]
    _check_values(path, union, flags, prog)
    return tyro.cli(union, args=[*flags, *args[len(typed):]], prog=prog)
