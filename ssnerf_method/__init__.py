"""SS-NeRF for nerfstudio: RGB plus semantics, normals, shading, keypoints and edges from one radiance field."""

from ssnerf_method.compat import allow_nerfstudio_checkpoints, quiet_known_warnings

quiet_known_warnings()  # first: the package's own imports below bring in torch and nerfstudio

from ssnerf_method.errors import install_error_hook  # noqa: E402

allow_nerfstudio_checkpoints()
install_error_hook()
