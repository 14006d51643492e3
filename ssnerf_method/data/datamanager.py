"""Datamanager config: nerfstudio's `VanillaDataManager` serving `SSNeRFDataset` from `SSNeRFDataParser`."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Type

from nerfstudio.data.datamanagers.base_datamanager import VanillaDataManager, VanillaDataManagerConfig

from ssnerf_method.data.dataparser import SSNeRFDataParserConfig
from ssnerf_method.data.dataset import SSNeRFDataset


@dataclass
class SSNeRFDataManagerConfig(VanillaDataManagerConfig):
    """Rays with RGB and every property label sampled at the same pixels."""

    _target: Type = field(default_factory=lambda: VanillaDataManager[SSNeRFDataset])
    dataparser: SSNeRFDataParserConfig = field(default_factory=SSNeRFDataParserConfig)
