"""Label generators shared by the synthetic scene and real data: pure numpy (and OpenCV) functions on images."""

from ssnerf_method.label_makers.edges import canny_edges
from ssnerf_method.label_makers.keypoints import keypoint_response_map
from ssnerf_method.label_makers.normals import backproject_depth, normals_from_depth, normals_from_points
from ssnerf_method.label_makers.shading import camera_ray_directions, lambertian_shading, shading_from_rays

__all__ = [
    "backproject_depth",
    "camera_ray_directions",
    "canny_edges",
    "keypoint_response_map",
    "lambertian_shading",
    "normals_from_depth",
    "normals_from_points",
    "shading_from_rays",
]
