"""`ssnerf-study`: the paper's studies, one subcommand each (`experiments/studies.py` for branches, rgb and multitask;
`experiments/transfer.py`, `experiments/augmentation.py`, `experiments/autolabel.py`, `experiments/sparsity.py`)."""

from __future__ import annotations

from typing import Union

import tyro
from typing_extensions import Annotated

from ssnerf_method.experiments.augmentation import AugmentationStudy
from ssnerf_method.experiments.autolabel import AutoLabelStudy
from ssnerf_method.experiments.sparsity import SparsityStudy
from ssnerf_method.experiments.studies import BranchStudy, MultiTaskStudy, RGBStudy
from ssnerf_method.experiments.transfer import TransferStudy

Study = Union[
    Annotated[BranchStudy, tyro.conf.subcommand("branches")],
    Annotated[RGBStudy, tyro.conf.subcommand("rgb")],
    Annotated[MultiTaskStudy, tyro.conf.subcommand("multitask")],
    Annotated[TransferStudy, tyro.conf.subcommand("transfer")],
    Annotated[AugmentationStudy, tyro.conf.subcommand("augmentation")],
    Annotated[AutoLabelStudy, tyro.conf.subcommand("autolabel")],
    Annotated[SparsityStudy, tyro.conf.subcommand("sparsity")],
]


def entrypoint() -> None:
    """Console script `ssnerf-study`."""
    tyro.cli(Study).run()  # type: ignore[union-attr]


if __name__ == "__main__":
    entrypoint()
