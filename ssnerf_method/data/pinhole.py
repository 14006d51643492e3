"""A pinhole camera as numpy sees it: lift a depth map to world points, project points, and tell which points a view
sees unhidden (the Heuristic baseline, the propagation study and `ssnerf-label --suggest-frames` share it)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Tuple

import numpy as np
from jaxtyping import Float

from nerfstudio.cameras.cameras import Cameras


@dataclass
class PinholeView:
    """One camera: intrinsics in nerfstudio's pixel convention (pixel (row i, column j) centred at (j + 0.5, i + 0.5))
    and its OpenGL camera-to-world (x right, y up, looking along -z)."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    camera_to_world: Float[np.ndarray, "3 4"]

    @classmethod
    def from_cameras(cls, cameras: Cameras, index: int) -> "PinholeView":
        camera = cameras[index]
        return cls(
            float(camera.fx), float(camera.fy), float(camera.cx), float(camera.cy), int(camera.width),
            int(camera.height), camera.camera_to_worlds.numpy().astype(np.float64),
        )

    @property
    def rotation(self) -> np.ndarray:
        return self.camera_to_world[:, :3]

    @property
    def centre(self) -> np.ndarray:
        return self.camera_to_world[:, 3]

    def unproject(self, depth: Float[np.ndarray, "h w"]) -> Tuple[Float[np.ndarray, "n 3"], np.ndarray]:
        """World points of the pixels with a depth (finite, > 0), and their flat pixel indices."""
        rows, cols = np.mgrid[0 : self.height, 0 : self.width]
        valid = np.isfinite(depth) & (depth > 0)
        z = depth[valid]
        x = (cols[valid] + 0.5 - self.cx) / self.fx * z
        y = -(rows[valid] + 0.5 - self.cy) / self.fy * z
        return np.stack([x, y, -z], axis=-1) @ self.rotation.T + self.centre, np.flatnonzero(valid.reshape(-1))

    def project(self, points: Float[np.ndarray, "n 3"]) -> Tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Pixel column, row and z-depth of each world point, and whether it lands in the image in front."""
        camera = (points - self.centre) @ self.rotation
        z = -camera[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            column = np.floor(self.fx * camera[:, 0] / z + self.cx)
            row = np.floor(-self.fy * camera[:, 1] / z + self.cy)
        inside = (z > 1e-9) & (column >= 0) & (column < self.width) & (row >= 0) & (row < self.height)
        return column, row, z, inside

    def sees(
        self, points: Float[np.ndarray, "n 3"], depth: Float[np.ndarray, "h w"], tolerance: float = 0.02
    ) -> np.ndarray:
        """Whether each world point is in the image and not hidden (depth there within relative `tolerance`)."""
        column, row, z, inside = self.project(points)
        seen = np.zeros(len(points), dtype=bool)
        there = depth[row[inside].astype(np.int64), column[inside].astype(np.int64)]
        seen[inside] = np.abs(there - z[inside]) <= tolerance * z[inside]
        return seen
