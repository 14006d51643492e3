"""SS-NeRF for nerfstudio: RGB plus semantics, normals, shading, keypoints and edges from one radiance field."""

from ssnerf_method.compat import allow_nerfstudio_checkpoints

allow_nerfstudio_checkpoints()
