"""Each ray's camera pose as ray metadata: what the pose-conditioned properties (normals in the paper's camera
frame, the pose input of `normals_mode="pose"`) read. The dataparser attaches it to every camera."""

from __future__ import annotations

from nerfstudio.cameras.cameras import Cameras

POSE_METADATA_KEY = "camera_to_world"
"""Ray metadata holding each ray's camera-to-world 3x4 matrix, flattened to 12 numbers."""


def add_pose_metadata(cameras: Cameras) -> Cameras:
    """Attach each camera's flattened camera-to-world matrix so its rays carry it (normals rotation, pose input)."""
    metadata = dict(cameras.metadata or {})
    metadata[POSE_METADATA_KEY] = cameras.camera_to_worlds.reshape(*cameras.camera_to_worlds.shape[:-2], 12)
    cameras.metadata = metadata
    return cameras
