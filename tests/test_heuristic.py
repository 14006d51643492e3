"""The Heuristic baseline's warp: exact on a plane under known camera motions (an integer-pixel sideways step, a
quarter turn about the optical axis, which also rotates normals), holes filled from the next view, then the nearest
pixel; and scored end to end on a generated scene, where it is far better than chance."""

from __future__ import annotations

import math
from typing import Dict, List

import numpy as np
import pytest
import torch

from nerfstudio.cameras.cameras import Cameras

from ssnerf_method.data.dataparser import SSNeRFDataParserConfig
from ssnerf_method.data.dataset import DEPTH_KEY, SSNeRFDataset
from ssnerf_method.evaluation.heuristic import (
    HeuristicBaseline,
    HeuristicBaselineConfig,
    NearestLabelledPoint,
    PinholeView,
    pose_distance,
)
from ssnerf_method.evaluation.scoring import score_predictor
from ssnerf_method.properties import REGISTRY, resolve_properties
from ssnerf_method.scene.make_scene import MakeSceneConfig, make_scene

SIZE, FOCAL, DEPTH = 16, 20.0, 2.0
CLASSES = 5


def pose(rotation: np.ndarray, centre) -> np.ndarray:
    c2w = np.zeros((3, 4))
    c2w[:, :3], c2w[:, 3] = rotation, centre
    return c2w


def quarter_turn() -> np.ndarray:
    """Rotation by +90 degrees about the camera's z axis."""
    return np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


class PlaneViews:
    """Stand-in for a training dataset: fronto-parallel plane at z-depth 2, random class ids and normals."""

    def __init__(self, poses: List[np.ndarray], seed: int = 0) -> None:
        rng = np.random.default_rng(seed)
        self.cameras = Cameras(
            camera_to_worlds=torch.tensor(np.stack(poses), dtype=torch.float32), fx=FOCAL, fy=FOCAL,
            cx=SIZE / 2, cy=SIZE / 2, width=SIZE, height=SIZE,
        )
        self.items = []
        for _ in poses:
            normals = rng.normal(size=(SIZE, SIZE, 3))
            normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
            self.items.append({
                "semantics": torch.from_numpy(rng.integers(0, CLASSES, (SIZE, SIZE, 1)).astype(np.float32)),
                "normals": torch.from_numpy((normals + 1) / 2).float(),
                DEPTH_KEY: torch.full((SIZE, SIZE, 1), DEPTH),
            })

    def __len__(self) -> int:
        return len(self.items)

    def __getitem__(self, index: int) -> Dict[str, torch.Tensor]:
        return self.items[index]


SPECS = [REGISTRY["semantics"], REGISTRY["normals"]]


def baseline(views: PlaneViews, num_source_views: int) -> HeuristicBaseline:
    return HeuristicBaseline(views, SPECS, CLASSES, dataparser_scale=1.0,  # type: ignore[arg-type]
                             config=HeuristicBaselineConfig(num_source_views=num_source_views))


def test_a_camera_sees_the_points_of_its_own_depth_and_not_those_behind_them_or_outside() -> None:
    """`PinholeView.sees`, which the propagation study counts test pixels a labelled frame sees with: the points a
    camera's own depth map unprojects to are seen, the same rays a fifth further on (hidden behind that surface) are
    not, and neither is a point behind the camera or beside its image."""
    view = PinholeView(FOCAL, FOCAL, SIZE / 2, SIZE / 2, SIZE, SIZE, pose(np.eye(3), [0.3, -0.2, 1.0]))
    depth = np.full((SIZE, SIZE), DEPTH)
    depth[:, : SIZE // 2] = DEPTH / 2  # a nearer half
    points, pixels = view.unproject(depth)
    assert len(points) == SIZE * SIZE and np.array_equal(pixels, np.arange(SIZE * SIZE))
    assert view.sees(points, depth).all()
    hidden = view.centre + (points - view.centre) * 1.2
    assert not view.sees(hidden, depth).any()
    beside = view.centre + np.array([[0.0, 0.0, 2.0], [5.0, 0.0, -DEPTH]])  # behind the camera; far off the image side
    assert not view.sees(beside, depth).any()


def test_sideways_step_shifts_labels_by_the_disparity() -> None:
    """Moving 0.3 sideways in front of a plane 2 away with focal 20 shifts the image by exactly 3 pixels."""
    views = PlaneViews([pose(np.eye(3), [0.0, 0.0, 0.0])])
    target = PinholeView(FOCAL, FOCAL, SIZE / 2, SIZE / 2, SIZE, SIZE, pose(np.eye(3), [0.3, 0.0, 0.0]))
    warped = baseline(views, 1).predict(target)
    source = views[0]
    torch.testing.assert_close(warped["semantics"][:, :-3], source["semantics"][:, 3:])
    torch.testing.assert_close(warped["normals"][:, :-3], source["normals"][:, 3:])  # same rotation: unchanged
    # The 3 columns the source never saw take the nearest filled pixel (the last warped column).
    for column in range(SIZE - 3, SIZE):
        torch.testing.assert_close(warped["semantics"][:, column], source["semantics"][:, SIZE - 1])


def test_quarter_turn_moves_pixels_and_rotates_normals() -> None:
    views = PlaneViews([pose(np.eye(3), [0.0, 0.0, 0.0])])
    turn = quarter_turn()
    target = PinholeView(FOCAL, FOCAL, SIZE / 2, SIZE / 2, SIZE, SIZE, pose(turn, [0.0, 0.0, 0.0]))
    warped = baseline(views, 1).predict(target)
    source = views[0]
    # The camera turned +90 degrees about its axis (counter-clockwise), so the image content turns clockwise:
    # target[r, c] = source[SIZE - 1 - c, r].
    expected_ids = torch.from_numpy(np.rot90(source["semantics"].numpy(), k=-1, axes=(0, 1)).copy())
    torch.testing.assert_close(warped["semantics"], expected_ids)
    source_normals = source["normals"].numpy() * 2 - 1
    expected = np.rot90(source_normals, k=-1, axes=(0, 1)) @ turn  # n_target = R_t^T n_source (row vectors)
    np.testing.assert_allclose(warped["normals"].numpy() * 2 - 1, expected, atol=1e-5)


def test_holes_come_from_the_next_nearest_view_first() -> None:
    """Three views: the target sits 0.3 right of view 0 (nearest) and view 1 sits 0.6 right; view 2 is far away.
    The columns view 0 cannot see come from view 1, shifted by its own disparity."""
    views = PlaneViews([pose(np.eye(3), [0.0, 0, 0]), pose(np.eye(3), [0.6, 0, 0]), pose(np.eye(3), [5.0, 0, 0])])
    target = PinholeView(FOCAL, FOCAL, SIZE / 2, SIZE / 2, SIZE, SIZE, pose(np.eye(3), [0.3, 0.0, 0.0]))
    model = baseline(views, 2)
    assert model.source_order(target)[:2] in ([0, 1], [1, 0])
    warped = model.predict(target)
    first, second = views[model.source_order(target)[0]], views[model.source_order(target)[1]]
    if model.source_order(target)[0] == 0:
        torch.testing.assert_close(warped["semantics"][:, :-3], first["semantics"][:, 3:])
        torch.testing.assert_close(warped["semantics"][:, -3:], second["semantics"][:, SIZE - 6 : SIZE - 3])
    else:
        torch.testing.assert_close(warped["semantics"][:, 3:], first["semantics"][:, :-3])
        torch.testing.assert_close(warped["semantics"][:, :3], second["semantics"][:, 3:6])


def test_nearest_labelled_point_gives_each_pixel_the_class_of_the_nearest_labelled_pixel_in_3d() -> None:
    views = PlaneViews([pose(np.eye(3), [0.0, 0.0, 0.0]), pose(np.eye(3), [0.5, 0.0, 0.0])])
    clicks = torch.full((SIZE, SIZE, 1), 255.0)
    clicks[8, 2], clicks[8, 13] = 1.0, 3.0  # two clicks on the plane, at x = -0.55 and x = 0.55
    views.items[0]["semantics"] = clicks
    views.items[1]["semantics"] = torch.full((SIZE, SIZE, 1), 255.0)  # a view without labels
    target_depth = np.full((SIZE, SIZE), DEPTH)
    target_depth[:, 0] = np.nan  # a column without depth takes its neighbour's class
    predict = NearestLabelledPoint(views, REGISTRY["semantics"], CLASSES,  # type: ignore[arg-type]
                                   lambda index: np.full((SIZE, SIZE), DEPTH), sources=[0, 1]).predictor(
        lambda cameras, index: target_depth)
    columns = torch.arange(SIZE).expand(SIZE, SIZE)
    # the first view: the class boundary (x = 0) between columns 7 and 8; every row alike (nearness in 3D, not on
    # the clicked row)
    assert torch.equal(predict(views.cameras, 0)["semantics"].argmax(-1), torch.where(columns < 8, 1, 3))
    # the second view, 0.5 to the right: x = 0 lies 5 pixels further left
    assert torch.equal(predict(views.cameras, 1)["semantics"].argmax(-1), torch.where(columns < 3, 1, 3))
    nothing = NearestLabelledPoint(views, REGISTRY["semantics"], CLASSES,  # type: ignore[arg-type]
                                   lambda index: np.full((SIZE, SIZE), DEPTH), sources=[1]).predictor(
        lambda cameras, index: target_depth)
    assert (nothing(views.cameras, 0)["semantics"].argmax(-1) == 0).all()  # no labelled pixel: void (0) everywhere


def test_pose_distance_prefers_the_same_viewing_direction() -> None:
    here = PinholeView(FOCAL, FOCAL, 8, 8, SIZE, SIZE, pose(np.eye(3), [0, 0, 0]))
    near_turned = PinholeView(FOCAL, FOCAL, 8, 8, SIZE, SIZE, pose(quarter_turn().T @ np.diag([1, 1, 1]), [0.1, 0, 0]))
    assert pose_distance(here, near_turned) == pytest.approx(0.1)  # a turn about the viewing axis costs nothing
    side = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])  # looking sideways: 90 degrees off
    assert pose_distance(here, PinholeView(FOCAL, FOCAL, 8, 8, SIZE, SIZE, pose(side, [0, 0, 0])), 0.5) == \
        pytest.approx(0.5 * math.pi / 2)


def test_scores_a_generated_scene(tmp_path) -> None:
    root = tmp_path / "scene"
    make_scene(MakeSceneConfig(output_dir=root, width=48, height=36, num_frames=20))
    parser = SSNeRFDataParserConfig(data=root).setup()
    train = SSNeRFDataset(parser.get_dataparser_outputs("train"))
    test = SSNeRFDataset(parser.get_dataparser_outputs("test"))
    specs = resolve_properties(list(train.metadata["available_properties"]))
    num_classes = len(train.metadata["semantic_classes"])
    heuristic = HeuristicBaseline(train, specs, num_classes, train.metadata["dataparser_scale"])
    scores = score_predictor(heuristic.predict_view, test, specs, num_classes)
    assert {"semantics_miou", "normals_l1", "shading_l1", "keypoints_l1", "edges_l1"} <= set(scores)
    assert "psnr" not in scores  # the baseline predicts properties, not RGB
    assert scores["semantics_acc"] > 0.6 and scores["normals_angle_median_deg"] < 20
    assert all(np.isfinite(value) for value in scores.values())


def test_scoring_keeps_to_the_pixels_it_is_given(tmp_path) -> None:
    root = tmp_path / "scene"
    make_scene(MakeSceneConfig(output_dir=root, width=32, height=24, num_frames=10))
    test = SSNeRFDataset(SSNeRFDataParserConfig(data=root).setup().get_dataparser_outputs("test"))
    spec = REGISTRY["semantics"]
    num_classes = len(test.metadata["semantic_classes"])

    def left_right(cameras, index: int) -> Dict[str, torch.Tensor]:
        """The true classes on the left half of the view, the next class on the right half."""
        ids = spec.label(test[index], num_classes)[..., 0].long().clamp(max=num_classes - 1)
        ids[:, ids.shape[1] // 2:] = (ids[:, ids.shape[1] // 2:] + 1) % num_classes
        return {spec.name: torch.nn.functional.one_hot(ids, num_classes).float()}

    left = torch.zeros(24, 32, dtype=torch.bool)
    left[:, :16] = True
    whole = score_predictor(left_right, test, [spec], num_classes)["semantics_acc"]
    on_left = score_predictor(left_right, test, [spec], num_classes, pixels={i: left for i in range(len(test))})
    on_right = score_predictor(left_right, test, [spec], num_classes, pixels={i: ~left for i in range(len(test))})
    assert on_left["semantics_acc"] == 1.0 and on_left["semantics_miou"] == 1.0
    assert on_right["semantics_acc"] == 0.0 and 0.0 < whole < 1.0


def test_warp_uses_the_given_depth_source_and_a_dataset_without_depth_is_named(tmp_path) -> None:
    root = tmp_path / "scene"
    make_scene(MakeSceneConfig(output_dir=root, width=32, height=24, num_frames=10))
    parser = SSNeRFDataParserConfig(data=root).setup()
    train = SSNeRFDataset(parser.get_dataparser_outputs("train"))
    test = SSNeRFDataset(parser.get_dataparser_outputs("test"))
    specs = [REGISTRY["semantics"]]
    num_classes = len(train.metadata["semantic_classes"])
    scale = train.metadata["dataparser_scale"]
    default = HeuristicBaseline(train, specs, num_classes, scale)
    same = HeuristicBaseline(train, specs, num_classes, scale, depth=default.depth)
    far = HeuristicBaseline(train, specs, num_classes, scale, depth=lambda index: 3.0 * default.depth(index))
    target = PinholeView.from_cameras(test.cameras, 0)
    truth = default.predict(target)["semantics"]
    assert torch.equal(same.predict(target)["semantics"], truth)
    assert not torch.equal(far.predict(target)["semantics"], truth)  # the warp follows the depth it is given

    train.depth_files = None  # as the paper's released data: labels, no depth maps
    with pytest.raises(ValueError, match="depth_file_path"):
        HeuristicBaseline(train, specs, num_classes, scale).predict(target)
