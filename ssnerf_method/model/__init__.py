"""The SS-NeRF model (nerfstudio `Model`) and its losses."""
