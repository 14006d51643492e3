"""SS-NeRF for nerfstudio: RGB plus semantics, normals, shading, keypoints and edges from one radiance field."""

from ssnerf_method.compat import allow_nerfstudio_checkpoints
from ssnerf_method.errors import install_error_hook

allow_nerfstudio_checkpoints()
install_error_hook()
