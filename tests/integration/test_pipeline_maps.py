"""Object maps from rendered detections (issue 13 part 3): ROSHAN's online state as map objects,
map errors against ground truth, and one tiny step of benchmarks/pipeline.py's mapper."""

import importlib.util
import pathlib

import numpy as np
import pytest

from jaxsem import mapping, planning, slam
from jaxsem.mapping import BuildingRenderer, robot_camera, robot_intrinsics

W, H = 160, 120
ROOT = pathlib.Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def scene(building):
    with BuildingRenderer(building, W, H) as sc:
        yield sc


def _door_views(building, objects, distance=3.0):
    """The entrance door k and three robot cameras in front of it, looking at it."""
    r0, c0, r1, c1 = building.exterior_doors[0]
    k = int(np.flatnonzero(np.all(objects.cells == [r0, c0, r1, c1], axis=1))[0])
    centre = 0.5 * (objects.box_min[k] + objects.box_max[k])
    mid = np.asarray(building.origin) + 0.5 * building.resolution * np.array(building.shape[::-1])
    normal = np.array([0.0, 1.0]) if (c1 - c0) >= (r1 - r0) else np.array([1.0, 0.0])
    normal *= np.sign(np.dot(centre[:2] - mid, normal)) or 1.0
    side = np.array([-normal[1], normal[0]])
    views = []
    for s in (-0.8, 0.0, 0.8):  # three places along the wall, each looking at the door
        eye = centre[:2] + distance * normal + s * side
        d = centre[:2] - eye
        views.append(robot_camera(eye, float(np.arctan2(d[1], d[0]))))
    return k, centre, views


@pytest.mark.slow  # compiling ROSHAN's online update takes over a minute on the 2-core CPU
def test_roshan_map_from_rendered_boxes_lands_on_the_door(building, scene):
    """Rendered boxes -> ROSHAN (known poses) -> map objects -> LSD's semantic grid: the door's
    footprint lies within two cells of the ground truth's, its centre within 0.3 m."""
    objects = scene.objects
    k, centre, views = _door_views(building, objects)
    K = robot_intrinsics(W, H)
    cap = slam.Capacity(max_poses=4, max_objects=len(objects), max_boxes=16, max_detections=4)
    state = mapping.roshan_init(K, (W, H), cap, optimize_every=1, iterations=10)
    for T in views:
        out = scene.render(K, T, outputs=("depth", "seg"))
        det = scene.detect(out["seg"], (planning.DOOR,), min_area=50)
        assert k in det.object_index
        i = det.object_index == k
        tex = [np.percentile(out["depth"][(out["seg"] == k) & (out["depth"] > 0)], 5)]
        frame = mapping.roshan_frame(
            T, det.box[i], det.class_id[i], det.object_index[i], tex, max_detections=4, image_size=(W, H)
        )
        state = slam.online_update(state, frame)
    ell = mapping.roshan_objects(state)
    assert np.asarray(ell.valid).tolist() == [j == k for j in range(len(objects))]
    assert int(ell.class_id[k]) == planning.DOOR
    np.testing.assert_allclose(np.asarray(ell.center[k]), centre, atol=0.3)
    grid = np.asarray(mapping.semantic_grid(ell, building.grid))
    rows, cols = np.nonzero(grid == planning.DOOR)
    r0, c0, r1, c1 = objects.cells[k]
    assert rows.size > 0
    assert rows.min() >= r0 - 2 and rows.max() <= r1 + 1 and cols.min() >= c0 - 2 and cols.max() <= c1 + 1
    # Its error against the true door, through map_errors, is the same small number.
    truth = objects.ellipsoids(len(objects))
    seen = np.arange(len(objects)) == k
    truth = mapping.Ellipsoids(truth.rotation, truth.center, truth.radii, truth.class_id, truth.valid & seen)
    err = mapping.map_errors(ell, truth)
    assert err["matched"].tolist() == seen.tolist()
    assert err["position"][k] < 0.3 and err["shape"][k] < 0.3
    assert np.isnan(err["position"][~seen]).all()


def test_map_scores_exact_shifted_and_missing(building):
    objs = mapping.building_objects(building)
    truth = objs.ellipsoids()
    exact = mapping.map_errors(mapping.ground_truth_map(building), truth)
    assert exact["matched"].all()
    np.testing.assert_allclose(exact["position"], 0.0, atol=1e-9)
    np.testing.assert_allclose(exact["shape"], 0.0, atol=1e-9)
    moved = mapping.Ellipsoids(
        truth.rotation, truth.center + np.array([0.3, 0.0, 0.0]), truth.radii, truth.class_id, truth.valid
    )
    shifted = mapping.map_errors(moved, truth, gate=0.5)
    # Greedy matching may pair a neighbour, but every error is at most the shift.
    assert shifted["matched"].all() and np.all(shifted["position"] <= 0.3 + 1e-9)
    empty = mapping.map_errors(mapping.init(4), truth)
    assert not empty["matched"].any() and np.isnan(empty["position"]).all()
    with pytest.raises(ValueError, match="truth"):
        mapping.map_errors(mapping.init(4), truth.center)


def test_roshan_priors_and_bad_class():
    mean, sigma = mapping.roshan_priors()
    assert mean.shape == sigma.shape == (len(mapping.ROSHAN_CLASSES), 3)
    assert tuple(mapping.ROSHAN_CLASSES) == (planning.DOOR, planning.WINDOW, planning.EXIT_SIGN)
    with pytest.raises(ValueError, match="semantic_class"):
        mapping.roshan_frame(np.eye(4), [[0, 0, 10, 10]], [planning.WALL], [0], max_detections=2)


def test_roshan_frame_refuses_an_off_image_box_given_the_image_size():
    box, door = [[2000, 10, 2100, 60]], [planning.DOOR]
    frame = mapping.roshan_frame(np.eye(4), box, door, [0], max_detections=2)  # no size: not checked
    assert np.asarray(frame.box_mask).tolist() == [True, False]
    with pytest.raises(ValueError, match="box"):
        mapping.roshan_frame(np.eye(4), box, door, [0], max_detections=2, image_size=(320, 240))
    inside = mapping.roshan_frame(np.eye(4), [[10, 10, 60, 60]], door, [0], max_detections=2, image_size=(320, 240))
    assert np.asarray(inside.box_mask).tolist() == [True, False]


def _pipeline():
    spec = importlib.util.spec_from_file_location("pipeline_bench", ROOT / "benchmarks" / "pipeline.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.slow
def test_pipeline_depth_mapper_one_step(building):
    """benchmarks/pipeline.py's DetectionMapper: one rendered view in front of the entrance door
    maps it (depth estimator), and its error against the seen door is small."""
    pipe = _pipeline()
    objects = mapping.building_objects(building)
    with BuildingRenderer(building, pipe.WIDTH, pipe.HEIGHT) as sc:
        k, _, views = _door_views(building, objects)
        T = views[1]
        eye = -T[:3, :3].T @ T[:3, 3]
        look = T[2, :3]  # the camera's optical axis in the world
        mapper = pipe.DetectionMapper(sc, objects, 64, "depth")
        mapper.observe(eye[:2], float(np.arctan2(look[1], look[0])))
        assert mapper.seen[k] and mapper.frames == 1
        e = mapper.errors()
        assert e["seen"] >= 1 and e["matched"] >= 1
        assert np.nanmedian(e["position"]) < 0.2
