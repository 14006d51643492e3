"""An optional training term: a config (its weight `mult`, its own settings) and a class that says which extra
training outputs it needs and what its loss is. The model calls every active one and knows nothing else of them."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar, Dict, NamedTuple, Optional, Type

from torch import Tensor

from nerfstudio.configs.base_config import InstantiateConfig
from nerfstudio.models.base_model import Model

from ssnerf_method.data.pixel_sampler import PATCH_RAYS
from ssnerf_method.rendering.sampling import SamplingResult

REGULARISERS: Dict[str, Type["RegulariserConfig"]] = {}
"""Every term by its name (the key of the model's `regularisers` and of its logged `<name>_loss`)."""


class PatchRequest(NamedTuple):
    """3x3 pixel patches a term wants in each training batch (the pipeline hands them to the pixel sampler)."""

    count: int
    """Patches per batch (9 rays each, first in the batch, in place of uniform rays)."""
    stride: Optional[int] = None
    """Pixels between a patch's neighbouring rays; None: the sampler's `smoothness_patch_stride`."""
    only_while_class_sparse: bool = False
    """Only while the class labels are sparse, from the frames that hold some (a term that spreads sparse labels)."""


@dataclass
class RegulariserConfig(InstantiateConfig):
    """One optional training term; a subclass with a `name` registers itself (`REGULARISERS`)."""

    _target: Type = field(default_factory=lambda: Regulariser)
    name: ClassVar[str] = ""
    mult: float = 0.0
    """Weight of the term's loss; 0: off (nothing is computed)."""

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if cls.name:
            REGULARISERS[cls.name] = cls

    def pixel_patches(self) -> Optional[PatchRequest]:
        """The pixel patches the term trains on, when it is on; None: plain rays."""
        return None


class Regulariser:
    """An optional training term: the outputs it needs from a training forward pass, and its weighted loss. Its
    methods get the `SSNeRFModel` they train (its `specs`, `rgb_spec`, `class_spec`, `num_classes`, `balancer`)."""

    def __init__(self, config: RegulariserConfig) -> None:
        self.config = config

    def active(self, model: Model) -> bool:
        """Whether the term trains this model (its weight is above 0 and what it acts on is trained)."""
        return self.config.mult > 0

    def outputs(self, model: Model, result: SamplingResult) -> Dict[str, Any]:
        """Extra outputs of a training forward pass that `loss` reads (none by default)."""
        return {}

    def loss(self, model: Model, outputs: Dict[str, Any], batch: Dict[str, Tensor]) -> Optional[Tensor]:
        """The term's loss times its `mult`, logged as `<name>_loss`; None where the batch gives it nothing to do."""
        raise NotImplementedError


def patch_colours(model: Model, batch: Dict[str, Tensor], patches: int) -> Tensor:
    """(patches, 9, 3) colours of the batch's first `patches` 3x3 pixel patches, which the patch terms weigh by."""
    colours = model.rgb_spec.label(batch, model.num_classes).to(model.device)[: patches * PATCH_RAYS]
    return colours.view(patches, PATCH_RAYS, -1)
