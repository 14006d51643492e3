"""The label makers on images and depth maps whose answer is known: Canny and keypoint heatmaps of a drawn image,
normals of a tilted plane and a sphere against the analytic normal (also through a distorted nerfstudio camera), the
guided smoothing of bumpy normals, and Lambertian shading of known normals."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ssnerf_method.data.transforms import Transforms, camera_rays, frame_camera
from ssnerf_method.label_makers import (
    camera_ray_directions,
    canny_edges,
    lambertian_shading,
    normals_from_depth,
    normals_from_points,
)
from ssnerf_method.label_makers.encoding import decode_normals
from ssnerf_method.label_makers.keypoints import keypoint_response_map
from ssnerf_method.label_makers.makers import FrameSources, LabelOptions, NormalsFromDepth, SemanticsCopy
from ssnerf_method.label_makers.normals import smooth_normals
from ssnerf_method.label_makers.segments import grow_in_segments

WIDTH, HEIGHT, FOCAL = 96, 72, 80.0
CX, CY = WIDTH / 2, HEIGHT / 2


def square_image() -> np.ndarray:
    """Dark image with a bright 20x30 rectangle: rows 20..39, columns 30..59."""
    image = np.full((HEIGHT, WIDTH, 3), 30, dtype=np.uint8)
    image[20:40, 30:60] = 220
    return image


def test_canny_marks_exactly_the_rectangle_outline() -> None:
    edges = canny_edges(square_image())
    assert edges.dtype == np.float32 and set(np.unique(edges)) == {0.0, 1.0}
    rows, cols = np.nonzero(edges)
    # Every edge pixel lies within one pixel of the rectangle's border, and every side is found.
    near_border = (np.minimum(np.abs(rows - 19.5), np.abs(rows - 39.5)) <= 1) | (
        np.minimum(np.abs(cols - 29.5), np.abs(cols - 59.5)) <= 1
    )
    inside = (rows >= 18) & (rows <= 41) & (cols >= 28) & (cols <= 61)
    assert (near_border & inside).all()
    for side in (edges[19:21, 35:55], edges[38:41, 35:55], edges[25:35, 29:31], edges[25:35, 58:61]):
        assert side.any(axis=0 if side.shape[0] <= 3 else 1).all()
    assert canny_edges(square_image(), 1000, 2000).sum() == 0  # thresholds above every gradient: no edges


def blob_image(centres, width: int = WIDTH, contrast: float = 180.0) -> np.ndarray:
    """A grey uint8 RGB image with a Gaussian blob (sigma 4 px) at each (x, y) in `centres`."""
    rows, cols = np.mgrid[0:HEIGHT, 0:width] + 0.5
    image = np.full((HEIGHT, width), 40.0)
    for x, y in centres:
        image += contrast * np.exp(-((cols - x) ** 2 + (rows - y) ** 2) / (2 * 4.0**2))
    return np.repeat(np.clip(image, 0, 255).astype(np.uint8)[..., None], 3, axis=-1)


def test_keypoint_response_map_peaks_on_the_blob_and_is_the_same_in_every_view() -> None:
    image = blob_image([(40.0, 30.0)])
    response = keypoint_response_map(image)
    assert response.dtype == np.float32 and response.shape == (HEIGHT, WIDTH)
    peak_row, peak_col = np.unravel_index(np.argmax(response), response.shape)
    assert abs(peak_row - 29.5) <= 1.5 and abs(peak_col - 39.5) <= 1.5 and response.max() > 0.5
    assert response[:, :15].max() < 0.01 and response.min() >= 0.0 and response.max() < 1.0
    assert keypoint_response_map(np.full((HEIGHT, WIDTH, 3), 90, dtype=np.uint8)).max() == 0.0  # flat: nothing
    # A fixed curve, not a per-image normalisation: a stronger second blob elsewhere leaves the first one's values
    # as they were.
    wider = blob_image([(40.0, 30.0), (120.0, 30.0)], width=160)
    wider[..., :] = np.where(np.arange(160)[None, :, None] < 80, wider, blob_image([(40.0, 30.0), (120.0, 30.0)],
                                                                                   width=160, contrast=215.0))
    assert np.array_equal(keypoint_response_map(wider)[:, 10:70], response[:, 10:70])


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.rad2deg(np.arccos(np.clip(np.einsum("...c,...c->...", a, b), -1.0, 1.0)))


def tilted_plane(rays: np.ndarray):
    """z-depth and analytic normal of the plane through (0, 0, -2) facing the camera, tilted ~20 deg."""
    normal = np.array([0.3, -0.2, 1.0]) / np.linalg.norm([0.3, -0.2, 1.0])
    distance = normal @ np.array([0.0, 0.0, -2.0])
    t = distance / (rays @ normal)
    return -t * rays[..., 2], normal


def test_normals_of_a_tilted_plane_match_the_analytic_normal() -> None:
    rays = camera_ray_directions(HEIGHT, WIDTH, FOCAL, FOCAL, CX, CY)
    depth, normal = tilted_plane(rays)
    normals = normals_from_depth(depth, FOCAL, FOCAL, CX, CY)
    assert np.isfinite(normals).all()
    assert _angle_deg(normals, normal).max() < 0.01
    # The paper's formula, on the back-projected points: (-dz/dx, -dz/dy, 1) in camera axes where z is the distance
    # in front of the camera (OpenCV: x right, y down, z forward), expressed back in OpenGL axes.
    points = depth[..., None] * rays / -rays[..., 2:]
    x, y, z = points[..., 0], -points[..., 1], -points[..., 2]  # OpenCV axes
    # Chain rule: the pixel derivatives of z are J @ (dz/dx, dz/dy), J the pixel derivatives of (x, y).
    jacobian = np.stack([np.stack([np.gradient(c, axis=a) for c in (x, y)], -1) for a in (1, 0)], -2)
    dz_dx, dz_dy = np.moveaxis(np.linalg.solve(jacobian, np.stack([np.gradient(z, axis=a) for a in (1, 0)], -1)), -1, 0)
    paper = np.stack([-dz_dx, -dz_dy, np.ones_like(z)], axis=-1)
    paper /= np.linalg.norm(paper, axis=-1, keepdims=True)
    # (-dz/dx, -dz/dy, 1) points away from the camera in OpenCV axes; flipped and mapped to OpenGL it is ours.
    paper_gl = -paper * np.array([1.0, -1.0, -1.0])
    assert _angle_deg(normals[2:-2, 2:-2], paper_gl[2:-2, 2:-2]).max() < 0.5


def test_normals_of_a_sphere_away_from_its_silhouette() -> None:
    rays = camera_ray_directions(HEIGHT, WIDTH, FOCAL, FOCAL, CX, CY)
    centre, radius = np.array([0.1, -0.05, -3.0]), 0.9
    b = rays @ centre
    disc = b**2 - (centre @ centre - radius**2)
    hit = disc > 0
    t = np.where(hit, b - np.sqrt(np.where(hit, disc, 0.0)), 0.0)
    points = t[..., None] * rays
    depth = np.where(hit, -points[..., 2], 0.0)  # background: invalid depth
    analytic = (points - centre) / radius
    normals = normals_from_depth(depth, FOCAL, FOCAL, CX, CY)
    assert np.isnan(normals[~hit]).all()
    # Away from the silhouette (the analytic normal still faces the camera by > 25 deg).
    interior = hit & (np.einsum("hwc,hwc->hw", analytic, -rays) > np.cos(np.deg2rad(65)))
    assert interior.sum() > 200
    errors = _angle_deg(normals[interior], analytic[interior])
    assert np.median(errors) < 0.5 and errors.max() < 3.0


def test_normals_through_a_distorted_nerfstudio_camera() -> None:
    """With radial distortion, pinhole back-projection would bend the plane; nerfstudio's own rays keep it flat."""
    meta = {"frames": [{"file_path": "x.png"}], "fl_x": FOCAL, "fl_y": FOCAL, "cx": CX, "cy": CY, "w": WIDTH,
            "h": HEIGHT, "camera_model": "OPENCV", "k1": -0.25, "k2": 0.05, "p1": 0.001, "p2": -0.001}
    rays = camera_rays(frame_camera(Transforms(Path("."), Path("t.json"), meta), meta["frames"][0]))
    assert rays.shape == (HEIGHT, WIDTH, 3)
    depth, normal = tilted_plane(rays)
    points = depth[..., None] * rays / -rays[..., 2:]
    normals = normals_from_points(points, depth > 0)
    assert _angle_deg(normals, normal).max() < 0.05
    pinhole = normals_from_depth(depth, FOCAL, FOCAL, CX, CY)
    assert np.nanmax(_angle_deg(pinhole, normal)) > 1.0  # ignoring the distortion would be visibly wrong


def test_smoothing_flattens_texture_bumps_and_keeps_the_image_edges() -> None:
    """Two walls meeting at column 48 (normals 60 degrees apart, a dark and a bright image side), each striped: the
    normals tilt 15 degrees with every stripe, as a radiance field's depth copies texture. Smoothing over 8 pixels
    removes the bumps, keeps each wall's normal up to the edge, and leaves unknown pixels unknown."""
    left, right = np.array([0.5, 0.0, np.sqrt(0.75)]), np.array([-0.5, 0.0, np.sqrt(0.75)])
    side = np.arange(WIDTH) < WIDTH // 2
    stripe = (np.arange(WIDTH) // 3) % 2 == 0
    image = np.where(side, 50, 200)[None, :, None] + np.where(stripe, 6, -6)[None, :, None]
    image = np.broadcast_to(image, (HEIGHT, WIDTH, 3)).astype(np.uint8)
    truth = np.where(side[None, :, None], left, right) * np.ones((HEIGHT, 1, 1))
    tilt = np.deg2rad(np.where(stripe, 15.0, -15.0))[None, :, None]
    bumpy = truth * np.cos(tilt) + np.array([0.0, 1.0, 0.0]) * np.sin(tilt)
    hole = np.zeros((HEIGHT, WIDTH), dtype=bool)
    hole[30:34, 10:14] = True
    bumpy[hole] = np.nan
    smoothed = smooth_normals(bumpy, image, radius=8)
    assert np.isnan(smoothed[hole]).all() and np.isfinite(smoothed[~hole]).all()
    known = ~hole
    assert np.median(_angle_deg(bumpy[known], truth[known])) > 14.0
    assert np.median(_angle_deg(smoothed[known], truth[known])) < 4.0
    edge = smoothed[:, WIDTH // 2 - 1 : WIDTH // 2 + 1]  # the last column of one wall, the first of the other
    assert _angle_deg(edge, truth[:, WIDTH // 2 - 1 : WIDTH // 2 + 1]).max() < 10.0  # a plain blur: 23


def test_normals_maker_smooths_only_when_the_frame_asks() -> None:
    """A tilted plane whose depth is ribbed along the stripes of its image (a radiance field's texture copy): the
    normals maker smooths them for a frame with `normals_smoothing` (rendered depth), not for one without (sensor)."""
    rays = camera_ray_directions(HEIGHT, WIDTH, FOCAL, FOCAL, CX, CY)
    depth, normal = tilted_plane(rays)
    stripe = (np.arange(WIDTH) // 3) % 2 == 0
    ribbed = depth * (1.0 + np.where(stripe, 0.004, -0.004))[None, :]
    image = np.broadcast_to(np.where(stripe, 120, 140)[None, :, None], (HEIGHT, WIDTH, 3)).astype(np.uint8)

    def errors(smoothing: int) -> np.ndarray:
        frame = FrameSources(rgb=image, rays=lambda scale: rays, depth=lambda: ribbed, normals_smoothing=smoothing)
        made = decode_normals(NormalsFromDepth().make(frame, LabelOptions())[..., :3] / 255.0)
        return _angle_deg(made / np.linalg.norm(made, axis=-1, keepdims=True), normal)

    assert np.median(errors(0)) > 10.0
    assert np.median(errors(8)) < 3.0


def test_lambertian_shading_of_known_normals() -> None:
    rays = camera_ray_directions(HEIGHT, WIDTH, FOCAL, FOCAL, CX, CY)
    facing = -rays  # every pixel's normal points back along its viewing ray: fully lit
    np.testing.assert_allclose(lambertian_shading(facing, FOCAL, FOCAL, CX, CY), 1.0, atol=1e-12)
    tilt = np.deg2rad(60.0)
    fronto = np.broadcast_to([0.0, np.sin(tilt), np.cos(tilt)], rays.shape)
    shading = lambertian_shading(fronto, FOCAL, FOCAL, CX, CY)
    np.testing.assert_allclose(shading, np.clip(-(rays @ fronto[0, 0]), 0, 1), atol=1e-12)
    # At the image centre the ray is (0, 0, -1): shading = cos(60 deg).
    assert shading[HEIGHT // 2, WIDTH // 2] == pytest.approx(0.5, abs=0.01)
    away = np.broadcast_to([0.0, 0.0, -1.0], rays.shape)  # facing away from the camera: unlit, not negative
    assert lambertian_shading(away, FOCAL, FOCAL, CX, CY).max() == 0.0
    unknown = np.full(rays.shape, np.nan)
    assert np.isnan(lambertian_shading(unknown, FOCAL, FOCAL, CX, CY)).all()


def _regions_image() -> np.ndarray:
    """48x32: a red left half, a blue right half holding a green 8x8 square, and a grey strip across the bottom."""
    image = np.zeros((32, 48, 3), np.uint8)
    image[:, :24] = (200, 40, 40)
    image[:, 24:] = (40, 40, 200)
    image[8:16, 32:40] = (40, 200, 40)
    image[26:] = (128, 128, 128)
    return image


def test_clicks_grow_over_their_image_segment_and_no_further() -> None:
    clicks = np.full((32, 48), 255, np.uint8)
    clicks[5, 5], clicks[20, 40] = 1, 2  # one click in the red half, one in the blue
    clicks[28, 4], clicks[28, 44] = 3, 1  # two classes in the grey strip
    grown = grow_in_segments(clicks, _regions_image(), scale=300)

    red, blue = np.zeros((32, 48), bool), np.zeros((32, 48), bool)
    red[:24, :22], blue[:24, 26:] = True, True  # (away from the edges, where the blur makes thin segments of its own)
    blue[6:18, 30:42] = False
    assert (grown[red] == 1).all() and (grown[blue] == 2).all()
    outside_red = np.ones((32, 48), bool)
    outside_red[:26, :24] = False
    outside_red[28, 44] = False  # (the click of class 1 in the strip)
    assert not (grown[outside_red] == 1).any() and not (grown[:, :24] == 2).any()
    assert (grown[8:16, 32:40] == 255).all()  # no click in the green square: it stays unlabelled
    strip = grown[26:].copy()
    assert strip[2, 4] == 3 and strip[2, 44] == 1  # clicks never change
    strip[2, 4] = strip[2, 44] = 255
    assert (strip == 255).all()  # two classes meet in the strip: it is not grown


def test_semantics_maker_grows_only_when_asked() -> None:
    clicks = np.full((32, 48), 255, np.uint8)
    clicks[5, 5] = 1
    frame = FrameSources(rgb=_regions_image(), rays=lambda scale: np.zeros((1, 1, 3)), semantics=lambda: clicks)
    maker = SemanticsCopy()
    assert (maker.make(frame, LabelOptions()) != 255).sum() == 1
    grown = maker.make(frame, LabelOptions(semantics_grow=300))
    assert (grown[:24, :22] == 1).all() and (grown[:, 24:] == 255).all()
    assert "grown" in maker.describe(LabelOptions(semantics_grow=300)) and "grown" not in maker.describe(LabelOptions())
