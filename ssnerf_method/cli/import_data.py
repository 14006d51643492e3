"""`ssnerf-import {paper-llff,semantic-nerf} SRC DST`: convert another dataset layout into the SS-NeRF format.

    ssnerf-import paper-llff SRC DST [--class-names ...] [--normals-axes LUB] [--test-every 8] [--overwrite]
    ssnerf-import semantic-nerf SRC DST [--downscale 1] [--replica-info PATH] [--overwrite]

The output is written next to DST and moved into place only when the whole import succeeded; a bad input stops with
one message naming the file and what to do.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from typing import Annotated

import tyro

from ssnerf_method.data.io import DatasetInputError
from ssnerf_method.importers import PaperLLFFImportConfig, SemanticNeRFImportConfig

Commands = (
    Annotated[PaperLLFFImportConfig, tyro.conf.subcommand("paper-llff")]
    | Annotated[SemanticNeRFImportConfig, tyro.conf.subcommand("semantic-nerf")]
)
"""One subcommand per source layout."""


def main(args: Sequence[str] | None = None) -> int:
    """Parse `args` (default: the command line), import, report; 0 on success, 1 on bad input."""
    config = tyro.cli(Commands, args=args, prog="ssnerf-import")  # type: ignore[call-overload]
    try:
        summary = config.run()
    except DatasetInputError as err:
        print(f"ssnerf-import: {err}", file=sys.stderr)
        return 1
    print(f"ssnerf-import: {summary.report()}")
    return 0


def entrypoint() -> None:
    """Console script `ssnerf-import`."""
    sys.exit(main())


if __name__ == "__main__":
    entrypoint()
