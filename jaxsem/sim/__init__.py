"""Deprecated: ROSHAN's simulator is :mod:`jaxsem.slam.sim`, the MuJoCo renderer
:mod:`jaxsem.data`, the rendered buildings :mod:`jaxsem.mapping`. The old names resolve here for
one release, with a :class:`DeprecationWarning`."""

from jaxsem._deprecated import moved_attribute as _moved_attribute

_MOVED = {
    "BASELINE": "jaxsem.slam.sim",
    "BuildingRenderer": "jaxsem.mapping",
    "ROSHAN": "jaxsem.slam.sim",
    "SHAPES": "jaxsem.data",
    "SceneDetections": "jaxsem.mapping",
    "SceneObject": "jaxsem.data",
    "SceneRenderer": "jaxsem.data",
    "SimConfig": "jaxsem.slam.sim",
    "SimulatedMap": "jaxsem.slam.sim",
    "bounding_ellipsoid_radii": "jaxsem.data",
    "box_iou": "jaxsem.slam.sim",
    "building_mjcf": "jaxsem.mapping",
    "camera_path": "jaxsem.slam.sim",
    "class_table": "jaxsem.slam.sim",
    "detect": "jaxsem.slam.sim",
    "detect_from_segmentation": "jaxsem.mapping",
    "ellipsoids_from_depth": "jaxsem.mapping",
    "ground_truth": "jaxsem.slam.sim",
    "initial_estimate": "jaxsem.slam.sim",
    "intrinsics": "jaxsem.slam.sim",
    "map_errors": "jaxsem.slam.sim",
    "mujoco_intrinsics": "jaxsem.data",
    "mujoco_quaternion": "jaxsem.data",
    "mujoco_view": "jaxsem.data",
    "perturb_poses": "jaxsem.slam.sim",
    "quadricslam_config": "jaxsem.slam.sim",
    "random_objects": "jaxsem.slam.sim",
    "render_views": "jaxsem.data",
    "robot_camera": "jaxsem.mapping",
    "robot_intrinsics": "jaxsem.mapping",
    "simulate": "jaxsem.slam.sim",
    "simulate_batch": "jaxsem.slam.sim",
    "simulate_views": "jaxsem.slam.sim",
    "solve_online": "jaxsem.slam.sim",
    "solver_config": "jaxsem.slam.sim",
    "thesis_config": "jaxsem.slam.sim",
    "to_problem": "jaxsem.slam.sim",
}


def __getattr__(name):
    return _moved_attribute("jaxsem.sim", _MOVED, name)
