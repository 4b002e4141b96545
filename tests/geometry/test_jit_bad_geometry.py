"""One counted round of bad geometry under ``jit``: no bad input may come back finite and valid.

Each case calls a public function of :mod:`jaxsem.quadrics` inside ``jax.jit`` with one bad
argument (passed as a traced argument, so the eager checks cannot see it) and reads the validity
output the function offers (``valid``, ``hit``, ``ok``, a ``with_valid=True`` mask, or the
:func:`~jaxsem.quadrics.cell_in_grid` of a cell). The case passes when every floating output is
finite and the mask is False: the caller can tell, under ``jit``, that the answer means nothing.
A good input through the same function must read valid (else the mask says nothing).
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsem import quadrics as q

NAN = np.nan
R0 = np.eye(3)
C0 = np.array([0.3, -0.2, 5.0])
r0 = np.array([0.5, 0.4, 0.3])
K0 = np.array([[525.0, 0.0, 320.0], [0.0, 520.0, 240.0], [0.0, 0.0, 1.0]])
T0 = np.eye(4)
BOX0 = np.array([300.0, 200.0, 340.0, 260.0])
ORIGIN0 = np.array([-1.0, -1.0])
RES0 = 0.25


def _set(x, index, value):
    x = np.array(x, dtype=np.float64)
    x[index] = value
    return x


def _a(x):
    return jnp.asarray(x, jnp.float32)


# --------------------------------------------------------------------------------------------
# The functions, each as f(bad argument) -> (value, valid); the other arguments are good.


def _bbox(arg):
    def f(x):
        args = {"rotation": R0, "center": C0, "radii": r0, "K": K0, "camera_T_world": T0}
        args[arg] = x
        return q.project_bbox(*(_a(v) if v is not x else x for v in args.values()))

    return f


def _conic_chain(arg):
    def f(x):
        args = {"rotation": R0, "center": C0, "radii": r0, "K": K0, "camera_T_world": T0}
        args = {k: (x if k == arg else _a(v)) for k, v in args.items()}
        Qs = q.dual_quadric(args["rotation"], args["center"], args["radii"])
        return q.conic_bbox(q.project_dual_conic(Qs, args["K"], args["camera_T_world"]))

    return f


def _cylinder(center):
    return q.cylinder_bbox(_a(R0), center, _a(r0), _a(K0), _a(T0))


def _texture(center):
    return q.texture_plane_depth(_a(R0), center, _a(r0), _a(T0))


def _camera_matrix(K):
    return q.camera_matrix(K, _a(T0), with_valid=True)


def _camera_matrix_pose(T):
    return q.camera_matrix(_a(K0), T, with_valid=True)


def _dual(radii):
    return q.dual_quadric(_a(R0), _a(C0), radii, with_valid=True)


def _project_points_K(K):
    return q.project_points(_a(C0), K, _a(T0), with_valid=True)[::2]


def _project_points(point):
    return q.project_points(point, _a(K0), _a(T0), with_valid=True)[::2]


def _back_project_K(K):
    return q.back_project(_a([300.0, 200.0]), 2.0, K, _a(T0), with_valid=True)


def _back_project_depth(depth):
    return q.back_project(_a([300.0, 200.0]), depth, _a(K0), _a(T0), with_valid=True)


def _camera_frame(T):
    R_c, t_c, valid = q.camera_frame(_a(R0), _a(C0), T, with_valid=True)
    return (R_c, t_c), valid


def _depth_from_box_K(K):
    return q.depth_from_box_size(_a(BOX0), K, _a(T0), _a(r0))


def _depth_from_box_rotation(R):
    return q.depth_from_box_size(_a(BOX0), _a(K0), _a(T0), _a(r0), rotation=R)


def _single_view(box):
    R, c, r, valid = q.single_view_ellipsoid(box, _a(K0), _a(T0), 2.0, _a(r0), with_valid=True)
    return (R, c, r), valid


def _single_view_K(K):
    R, c, r, valid = q.single_view_ellipsoid(_a(BOX0), K, _a(T0), 2.0, _a(r0), with_valid=True)
    return (R, c, r), valid


def _look_at(target):
    return q.look_at(_a([1.0, 2.0, 3.0]), target, with_valid=True)


def _quaternion_wxyz(quat):
    return q.quaternion_wxyz_to_rotation(quat, with_valid=True)


def _quaternion_xyzw(quat):
    return q.quaternion_xyzw_to_rotation(quat, with_valid=True)


def _to_quaternion(R):
    return q.rotation_to_quaternion_wxyz(R, with_valid=True)


def _nearest(M):
    return q.nearest_rotation(M, with_valid=True)


def _raster(arg):
    def f(x):
        args = {"rotation": R0, "center": [0.0, 0.0, 0.0], "radii": r0, "origin": ORIGIN0, "resolution": RES0}
        args = {k: (x if k == arg else _a(v)) for k, v in args.items()}
        grid, valid = q.rasterize_footprint(
            args["rotation"],
            args["center"],
            args["radii"],
            1,
            (8, 8),
            args["origin"],
            args["resolution"],
            with_valid=True,
        )
        return grid.astype(jnp.float32), valid

    return f


def _ground(radii):
    return q.ground_bounds(_a(R0), _a(C0), radii, with_valid=True)


def _ground_conic(radii):
    return q.conic_bbox(q.ground_conic(_a(R0), _a(C0), radii))


def _cell(arg):
    def f(x):
        args = {"xy": [0.1, 0.1], "origin": ORIGIN0, "resolution": RES0}
        args = {k: (x if k == arg else _a(v)) for k, v in args.items()}
        rc = q.world_to_cell(args["xy"], args["origin"], args["resolution"])
        return rc, q.cell_in_grid(rc, (8, 8))

    return f


def _ray_entry(arg, shape=q.SHAPE_ELLIPSOID):
    def f(x):
        args = {"rotation": R0, "center": C0, "radii": r0}
        args = {k: (x if k == arg else _a(v)) for k, v in args.items()}
        return q.ray_entry_range(_a([[0.3, -0.2, 5.0]]), args["rotation"], args["center"], args["radii"], shape)

    return f


def _ray_cast(radii):
    s, hit, normal = q.ray_cast_local(_a([0.0, 0.0, -5.0]), _a([0.0, 0.0, 1.0]), radii, q.SHAPE_ELLIPSOID)
    return (s, normal), hit


def _conic(C):
    return q.conic_bbox(C)


def _outline(C):
    return q.conic_outline(C, 8)


def _shape_cuboid(center):
    return q.shape_bbox(_a(R0), center, _a(r0), q.SHAPE_CUBOID, _a(K0), _a(T0))


def _camera_valid(K):
    return K, q.camera_valid(K, _a(T0))


def _ellipsoid_valid(R):
    return R, q.ellipsoid_valid(R, _a(C0), _a(r0))


K_BOTTOM_ZERO = _set(K0, 2, 0.0)
ELLIPSE = np.diag([100.0, 400.0, -1.0])  # an ellipse of semi-axes 10 and 20 pixels about the origin
POINT_CONIC = -np.outer([100.0, 50.0, 1.0], [100.0, 50.0, 1.0])

# name -> (function of one traced argument, the good value, the bad value).
CASES = {
    # intrinsics
    "project_bbox-K-bottom-row-zero": (_bbox("K"), K0, K_BOTTOM_ZERO),
    "project_bbox-K-focal-zero": (_bbox("K"), K0, _set(K0, (0, 0), 0.0)),
    "project_bbox-K-nan": (_bbox("K"), K0, _set(K0, (1, 2), NAN)),
    "camera_matrix-K-bottom-row-nan": (_camera_matrix, K0, _set(K0, 2, NAN)),
    "camera_matrix-K-focal-negative": (_camera_matrix, K0, _set(K0, (1, 1), -520.0)),
    "camera_valid-K-bottom-row-zero": (_camera_valid, K0, K_BOTTOM_ZERO),
    "conic_chain-K-bottom-row-zero": (_conic_chain("K"), K0, K_BOTTOM_ZERO),
    "project_points-K-bottom-row-zero": (_project_points_K, K0, K_BOTTOM_ZERO),
    "back_project-K-focal-zero": (_back_project_K, K0, _set(K0, (0, 0), 0.0)),
    "depth_from_box_size-K-bottom-row-zero": (_depth_from_box_K, K0, K_BOTTOM_ZERO),
    "single_view_ellipsoid-K-bottom-row-zero": (_single_view_K, K0, K_BOTTOM_ZERO),
    # poses and rotations
    "project_bbox-rotation-doubled": (_bbox("rotation"), R0, 2.0 * R0),
    "project_bbox-rotation-nan": (_bbox("rotation"), R0, _set(R0, (0, 1), NAN)),
    "project_bbox-pose-reflection": (_bbox("camera_T_world"), T0, np.diag([1.0, -1.0, 1.0, 1.0])),
    "camera_matrix-pose-scaled": (_camera_matrix_pose, T0, np.diag([2.0, 2.0, 2.0, 1.0])),
    "camera_frame-pose-nan": (_camera_frame, T0, _set(T0, (1, 3), NAN)),
    "ellipsoid_valid-rotation-reflection": (_ellipsoid_valid, R0, np.diag([1.0, 1.0, -1.0])),
    "conic_chain-rotation-doubled": (_conic_chain("rotation"), R0, 2.0 * R0),
    "depth_from_box_size-rotation-doubled": (_depth_from_box_rotation, R0, 2.0 * R0),
    "rotation_to_quaternion-not-orthonormal": (_to_quaternion, R0, _set(R0, (0, 1), 0.5)),
    "nearest_rotation-reflection": (_nearest, R0, -R0),
    "nearest_rotation-nan": (_nearest, R0, _set(R0, (2, 2), NAN)),
    "quaternion_wxyz-zero": (_quaternion_wxyz, [1.0, 0.0, 0.0, 0.0], np.zeros(4)),
    "quaternion_xyzw-zero": (_quaternion_xyzw, [0.0, 0.0, 0.0, 1.0], np.zeros(4)),
    "quaternion_wxyz-nan": (_quaternion_wxyz, [1.0, 0.0, 0.0, 0.0], [NAN, 0.0, 0.0, 1.0]),
    "look_at-eye-on-target": (_look_at, [4.0, 2.0, 3.0], [1.0, 2.0, 3.0]),
    "look_at-target-nan": (_look_at, [4.0, 2.0, 3.0], [NAN, 2.0, 3.0]),
    # radii
    "project_bbox-radii-negative": (_bbox("radii"), r0, -r0),
    "conic_chain-radii-negative": (_conic_chain("radii"), r0, -r0),
    "conic_chain-radius-zero": (_conic_chain("radii"), r0, _set(r0, 1, 0.0)),
    "dual_quadric-radii-nan": (_dual, r0, _set(r0, 0, NAN)),
    "ground_bounds-radii-negative": (_ground, r0, -r0),
    "ground_conic-radii-negative": (_ground_conic, r0, -r0),
    "ray_entry_range-radii-negative": (_ray_entry("radii"), r0, -r0),
    "ray_entry_range-cuboid-radii-negative": (_ray_entry("radii", q.SHAPE_CUBOID), r0, -r0),
    "ray_entry_range-cylinder-radii-negative": (_ray_entry("radii", q.SHAPE_CYLINDER), r0, -r0),
    "ray_entry_range-rotation-doubled": (_ray_entry("rotation"), R0, 2.0 * R0),
    "ray_cast_local-radius-negative": (_ray_cast, r0, _set(r0, 0, -0.5)),
    "rasterize_footprint-radii-inf": (_raster("radii"), r0, _set(r0, 2, np.inf)),
    # centres and points
    "rasterize_footprint-centre-nan": (_raster("center"), [0.0, 0.0, 0.0], [NAN, 0.0, 0.0]),
    "ray_entry_range-centre-nan": (_ray_entry("center"), C0, _set(C0, 0, NAN)),
    "project_points-point-nan": (_project_points, C0, _set(C0, 1, NAN)),
    "back_project-depth-nan": (_back_project_depth, 2.0, NAN),
    "single_view_ellipsoid-box-nan": (_single_view, BOX0, _set(BOX0, 0, NAN)),
    # what the camera cannot see
    "project_bbox-behind-camera": (_bbox("center"), C0, -C0),
    "project_bbox-camera-inside": (_bbox("center"), C0, [0.0, 0.0, 0.1]),
    "conic_chain-behind-camera": (_conic_chain("center"), C0, -C0),
    "conic_chain-camera-inside": (_conic_chain("center"), C0, [0.0, 0.0, 0.1]),
    "cylinder_bbox-behind-camera": (_cylinder, C0, -C0),
    "texture_plane_depth-behind-camera": (_texture, C0, -C0),
    "shape_bbox-cuboid-straddling": (_shape_cuboid, C0, [0.0, 0.0, 0.2]),
    "project_points-behind-camera": (_project_points, C0, -C0),
    # conics that are no ellipse
    "conic_bbox-zero": (_conic, ELLIPSE, np.zeros((3, 3))),
    "conic_bbox-point": (_conic, ELLIPSE, POINT_CONIC),
    "conic_bbox-hyperbola": (_conic, ELLIPSE, np.diag([1.0, -1.0, -1.0])),
    "conic_bbox-imaginary": (_conic, ELLIPSE, np.diag([-1.0, -1.0, -1.0])),
    "conic_bbox-nan": (_conic, ELLIPSE, np.full((3, 3), NAN)),
    "conic_outline-point": (_outline, ELLIPSE, POINT_CONIC),
    # grids
    "world_to_cell-xy-nan": (_cell("xy"), [0.1, 0.1], [NAN, 0.1]),
    "world_to_cell-origin-nan": (_cell("origin"), ORIGIN0, [-1.0, NAN]),
    "world_to_cell-resolution-nan": (_cell("resolution"), RES0, NAN),
    "world_to_cell-resolution-negative": (_cell("resolution"), RES0, -RES0),
    "rasterize_footprint-origin-nan": (_raster("origin"), ORIGIN0, [NAN, -1.0]),
    "rasterize_footprint-resolution-zero": (_raster("resolution"), RES0, 0.0),
    "rasterize_footprint-resolution-nan": (_raster("resolution"), RES0, NAN),
}


def _run(case, value):
    f = CASES[case][0]
    out, valid = jax.jit(f)(_a(value))
    leaves = [x for x in jax.tree_util.tree_leaves(out) if jnp.issubdtype(x.dtype, jnp.floating)]
    finite = all(bool(jnp.all(jnp.isfinite(x))) for x in leaves)
    return finite, bool(jnp.any(valid))


def test_the_round_is_counted():
    assert len(CASES) >= 45


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_geometry_under_jit_is_finite_and_reads_invalid(case):
    _, good, bad = CASES[case]
    finite, valid = _run(case, good)
    assert finite and valid, f"{case}: the good input must read finite and valid"
    finite, valid = _run(case, bad)
    assert finite, f"{case}: non-finite output for the bad input"
    assert not valid, f"{case}: the bad input reads valid"
