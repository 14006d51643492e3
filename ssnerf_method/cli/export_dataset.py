"""`ssnerf-export-dataset`: a trained model's renders written as a new SS-NeRF dataset (`export/dataset.py`)."""

from __future__ import annotations

import sys
import time

import tyro

from nerfstudio.utils.rich_utils import CONSOLE

from ssnerf_method.data.io import DatasetInputError
from ssnerf_method.export.dataset import ExportDatasetConfig, export_dataset


def entrypoint() -> None:
    """Console script `ssnerf-export-dataset`."""
    config = tyro.cli(ExportDatasetConfig)
    start = time.perf_counter()
    try:
        path = export_dataset(config)
    except DatasetInputError as err:
        sys.exit(f"ssnerf-export-dataset: {err}")
    CONSOLE.print(f"ssnerf-export-dataset: wrote {path} in {time.perf_counter() - start:.1f} s. Train on it with "
                  f"`ns-train ssnerf-lite --data {path.parent}`.")


if __name__ == "__main__":
    entrypoint()
