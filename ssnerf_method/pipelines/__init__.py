"""The SS-NeRF training and evaluation pipeline (nerfstudio's `VanillaPipeline` with split-level metrics)."""
