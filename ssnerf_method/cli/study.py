"""`ssnerf-study`: the paper's studies, one subcommand each (`experiments/studies.py` for branches, rgb and multitask;
`experiments/transfer.py`, `experiments/augmentation.py`, `experiments/autolabel.py`, `experiments/sparsity.py`,
`experiments/propagation.py`)."""

from __future__ import annotations

from typing import Dict, Optional, Sequence, Type, Union

import tyro
from typing_extensions import Annotated

from ssnerf_method.errors import UserError, exit_with
from ssnerf_method.experiments import presets
from ssnerf_method.experiments.augmentation import AugmentationStudy
from ssnerf_method.experiments.autolabel import AutoLabelStudy
from ssnerf_method.experiments.propagation import PropagationStudy
from ssnerf_method.experiments.sparsity import SparsityStudy
from ssnerf_method.experiments.studies import BranchStudy, ClassGridStudy, MultiTaskStudy, RGBStudy
from ssnerf_method.experiments.transfer import TransferStudy

STUDIES: Dict[str, Type] = {
    "branches": BranchStudy,
    "rgb": RGBStudy,
    "multitask": MultiTaskStudy,
    "transfer": TransferStudy,
    "augmentation": AugmentationStudy,
    "autolabel": AutoLabelStudy,
    "sparsity": SparsityStudy,
    "propagation": PropagationStudy,
    "class-grid": ClassGridStudy,
}
"""Each subcommand's study."""

Study = Union[tuple(Annotated[study, tyro.conf.subcommand(name)] for name, study in STUDIES.items())]  # type: ignore


def parse(args: Optional[Sequence[str]] = None):
    """The study the command line (or `args`) asks for; `--preset configs/<study>.yaml` names it and its options."""
    return presets.study_cli(STUDIES, Study, "ssnerf-study", args)


def entrypoint() -> None:
    """Console script `ssnerf-study`."""
    try:
        parse().run()
    except UserError as err:
        exit_with(err, "ssnerf-study")


if __name__ == "__main__":
    entrypoint()
