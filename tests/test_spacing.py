"""`data/spacing.py`: how far test views are from training views, on poses whose answer is known by hand."""

from __future__ import annotations

import numpy as np

from ssnerf_method.data.spacing import pose_spacing


def pose(x: float, yaw_deg: float) -> np.ndarray:
    """Camera at (x, 0, 0) looking along -z turned by `yaw_deg` about +y (camera-to-world, OpenGL)."""
    yaw = np.deg2rad(yaw_deg)
    matrix = np.eye(4)
    matrix[:3, :3] = [[np.cos(yaw), 0, np.sin(yaw)], [0, 1, 0], [-np.sin(yaw), 0, np.cos(yaw)]]
    matrix[0, 3] = x
    return matrix


def test_nearest_view_is_ranked_by_distance_plus_angle_and_its_median_reported() -> None:
    train = np.stack([pose(0.0, 0.0), pose(1.0, 0.0), pose(0.35, 60.0)])
    test = np.stack([pose(0.2, 0.0), pose(0.9, 10.0), pose(2.0, 0.0)])
    spacing = pose_spacing(train, test)
    # nearest: 0.2 m/0° (to x=0), 0.1 m/10° (to x=1), 1.0 m/0° (to x=1); the view at 0.35 m looks 60° away
    assert spacing["test_views"] == 3
    assert np.isclose(spacing["median_m"], 0.2) and np.isclose(spacing["median_deg"], 0.0)
    assert np.isclose(pose_spacing(train, test[1:2])["median_deg"], 10.0)
    # 0.05 m away but turned 90°: 0.05 + 0.5 * pi/2 loses to 0.9 m straight on
    assert np.isclose(pose_spacing(np.stack([pose(0.05, 90.0), pose(0.9, 0.0)]), test[:1])["median_m"], 0.7)


def test_no_test_views_reports_nothing() -> None:
    assert pose_spacing(np.stack([pose(0.0, 0.0)]), np.zeros((0, 4, 4))) == {
        "median_m": None, "median_deg": None, "test_views": 0}
