"""Nothing silent in the geometry core (issue 26, items 1 and 2).

A table of bad inputs goes through every core function twice: eagerly (a ``ValueError`` naming the
argument) and under ``jit`` (``valid`` False, values finite, gradients finite), in float32 and
float64. Then the float32 conic chain against float64 over 10,000 random valid views, and its
forward-mode Jacobian. The references are independent of the formulas under test: a view is
"valid" by construction (the ellipsoid well in front of the camera, centre in the field of view),
and the float32 answer is compared with the float64 one.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsem import quadrics as q

pytestmark = pytest.mark.filterwarnings("error")

DTYPES = [np.float32, np.float64]

R0 = np.eye(3)
C0 = np.array([0.3, -0.2, 5.0])
r0 = np.array([0.5, 0.4, 0.3])
K0 = np.array([[525.0, 0.0, 320.0], [0.0, 520.0, 240.0], [0.0, 0.0, 1.0]])
T0 = np.eye(4)

_NAN = np.nan


def _set(x, index, value):
    x = np.array(x, dtype=np.float64)
    x[index] = value
    return x


# name -> (argument, bad value). Each is something the eager checks refuse.
BAD = {
    "radii_negative": ("radii", -r0),
    "radii_zero": ("radii", _set(r0, 1, 0.0)),
    "radii_nan": ("radii", _set(r0, 1, _NAN)),
    "radii_inf": ("radii", _set(r0, 2, np.inf)),
    "rotation_doubled": ("rotation", 2.0 * R0),
    "rotation_reflection": ("rotation", np.diag([1.0, 1.0, -1.0])),
    "rotation_zero": ("rotation", np.zeros((3, 3))),
    "rotation_nan": ("rotation", _set(R0, (0, 1), _NAN)),
    "center_nan": ("center", _set(C0, 0, _NAN)),
    "focal_zero": ("K", _set(K0, (0, 0), 0.0)),
    "focal_negative": ("K", _set(K0, (1, 1), -520.0)),
    "intrinsics_nan": ("K", _set(K0, (0, 2), _NAN)),
    "intrinsics_bottom_one_zero": ("K", _set(K0, (2, 2), 0.0)),
    "intrinsics_bottom_row_zero": ("K", np.vstack([K0[:2], np.zeros((1, 3))])),
    "intrinsics_lower_left": ("K", _set(K0, (2, 0), 0.3)),
    "intrinsics_below_fx": ("K", _set(K0, (1, 0), 5.0)),
    "pose_scaled": ("camera_T_world", np.diag([3.0, 3.0, 3.0, 1.0])),
    "pose_reflection": ("camera_T_world", np.diag([1.0, -1.0, 1.0, 1.0])),
    "pose_last_row": ("camera_T_world", _set(T0, (3, 0), 0.5)),
    "pose_nan": ("camera_T_world", _set(T0, (1, 3), _NAN)),
}


def _conic_chain(R, c, r, K, T):
    return q.conic_bbox(q.project_dual_conic(q.dual_quadric(R, c, r), K, T))


def _outline(R, c, r, K, T):
    return q.conic_outline(q.project_dual_conic(q.dual_quadric(R, c, r), K, T), 8)


def _points(R, c, r, K, T):
    return q.project_points(c, K, T, with_valid=True)[::2]


def _frame(R, c, r, K, T):
    R_c, t_c, valid = q.camera_frame(R, c, T, with_valid=True)
    return jnp.concatenate([R_c.reshape(-1), t_c]), valid


def _quaternion(R, c, r, K, T):
    return q.rotation_to_quaternion_wxyz(R, with_valid=True)


def _raster(R, c, r, K, T):
    grid, valid = q.rasterize_footprint(R, c, r, 1, (6, 6), jnp.zeros(2, c.dtype), 0.5, with_valid=True)
    return grid.astype(c.dtype), valid


def _back(R, c, r, K, T):
    return q.back_project(jnp.asarray([300.0, 200.0], c.dtype), c[2], K, T, with_valid=True)


def _depth_from_box(R, c, r, K, T):
    return q.depth_from_box_size(jnp.asarray([300.0, 200.0, 340.0, 260.0], c.dtype), K, T, r)


def _shape(R, c, r, K, T):
    return q.shape_bbox(R, c, r, q.SHAPE_CYLINDER, K, T)


# name -> (function of (R, c, r, K, T) returning (value, valid), the arguments it reads).
FUNCTIONS = {
    "project_bbox": (q.project_bbox, {"rotation", "center", "radii", "K", "camera_T_world"}),
    "texture_plane_depth": (
        lambda R, c, r, K, T: q.texture_plane_depth(R, c, r, T),
        {"rotation", "center", "radii", "camera_T_world"},
    ),
    "cylinder_bbox": (q.cylinder_bbox, {"rotation", "center", "radii", "K", "camera_T_world"}),
    "shape_bbox": (_shape, {"rotation", "center", "radii", "K", "camera_T_world"}),
    # dual_quadric and project_dual_conic have no mask of their own: a bad ellipsoid or camera
    # gives the zero matrix, which conic_bbox reads as invalid (a sign flip of the radii would
    # otherwise give the very conic of the positive ones).
    "conic_chain": (_conic_chain, {"rotation", "center", "radii", "K", "camera_T_world"}),
    "conic_outline": (_outline, {"rotation", "center", "radii", "K", "camera_T_world"}),
    "back_project": (_back, {"K", "camera_T_world"}),
    "depth_from_box_size": (_depth_from_box, {"radii", "K", "camera_T_world"}),
    "project_points": (_points, {"center", "K", "camera_T_world"}),
    "camera_frame": (_frame, {"rotation", "center", "camera_T_world"}),
    "rotation_to_quaternion": (_quaternion, {"rotation"}),
    "rasterize_footprint": (_raster, {"rotation", "center", "radii"}),
}

_ARG_ORDER = ["rotation", "center", "radii", "K", "camera_T_world"]


def _cases():
    for fn, (_, reads) in FUNCTIONS.items():
        for bad, (arg, _) in BAD.items():
            if arg in reads or bad in reads:
                yield fn, bad


def _args(bad, dtype):
    values = {"rotation": R0, "center": C0, "radii": r0, "K": K0, "camera_T_world": T0}
    arg, value = BAD[bad]
    values[arg] = value
    return tuple(jnp.asarray(values[k], dtype) for k in _ARG_ORDER)


_JITTED = {}


def _jitted(fn):
    """Module-level cache: one compiled program per function (and dtype) giving the value, the
    mask and the gradient of the summed value, vmapped over a stack of cases."""
    if fn not in _JITTED:
        f = FUNCTIONS[fn][0]
        grad = jax.grad(lambda *a: jnp.sum(f(*a)[0]), argnums=(0, 1, 2, 3, 4))
        _JITTED[fn] = jax.jit(jax.vmap(lambda *a: (*f(*a), grad(*a))))
    return _JITTED[fn]


def _good(dtype):
    return tuple(jnp.asarray(x, dtype) for x in (R0, C0, r0, K0, T0))


@pytest.mark.parametrize("dtype", DTYPES, ids=["f32", "f64"])
@pytest.mark.parametrize("fn", sorted(FUNCTIONS))
def test_bad_inputs_under_jit_read_invalid_with_finite_values_and_gradients(fn, dtype):
    bads = [bad for f, bad in _cases() if f == fn]
    cases = [_good(dtype)] + [_args(bad, dtype) for bad in bads]
    stacked = [jnp.stack(a) for a in zip(*cases)]
    value, valid, grads = _jitted(fn)(*stacked)
    axes = tuple(range(1, valid.ndim))
    valid = np.asarray(jnp.any(valid, axis=axes) if axes else valid)
    assert valid[0], f"{fn} says invalid for the good input"
    said_valid = [bad for bad, v in zip(bads, valid[1:]) if v]
    assert not said_valid, f"{fn} says valid for {said_valid}"
    finite = np.asarray(jnp.all(jnp.isfinite(value.reshape(len(cases), -1)), -1))
    # The conic route passes through dual_quadric and project_dual_conic, which have no mask and
    # keep a NaN input NaN (documented): its box is finite, its gradient for a NaN is not checked.
    for g in grads if fn not in ("conic_chain", "conic_outline") else ():
        finite = finite & np.asarray(jnp.all(jnp.isfinite(g.reshape(len(cases), -1)), -1))
    assert finite.all(), (
        f"{fn}: non-finite value or gradient for {[(['good'] + bads)[i] for i in np.flatnonzero(~finite)]}"
    )


@pytest.mark.parametrize("fn, bad", [c for c in _cases() if c[0] not in ("conic_chain", "conic_outline")])
def test_bad_input_eagerly_is_refused_naming_the_argument(fn, bad):
    arg = BAD[bad][0]
    if fn == "project_points" and arg == "center":
        arg = "points"
    with pytest.raises(ValueError, match=arg):
        FUNCTIONS[fn][0](*_args(bad, np.float64))


def test_rotation_to_quaternion_refuses_a_non_rotation_eagerly():
    with pytest.raises(ValueError, match="rotation"):
        q.rotation_to_quaternion_wxyz(2.0 * np.eye(3))
    with pytest.raises(ValueError, match="rotation"):
        q.rotation_to_quaternion_xyzw(np.diag([1.0, -1.0, 1.0]))
    # A proper rotation goes through unchanged, with or without the mask.
    R = np.asarray(q.random_rotation(jax.random.PRNGKey(0)))
    quat, ok = q.rotation_to_quaternion_xyzw(R, with_valid=True)
    np.testing.assert_allclose(quat, q.rotation_to_quaternion_xyzw(R))
    assert bool(ok)


@pytest.mark.parametrize("dtype", DTYPES, ids=["f32", "f64"])
def test_look_at_with_eye_on_target_says_so_under_jit(dtype):
    f = jax.jit(lambda e, t: q.look_at(e, t, with_valid=True))
    eye = jnp.asarray([[1.0, 2.0, 3.0], [1.0, 2.0, 3.0], [0.0, 0.0, 0.0], [_NAN, 0.0, 0.0]], dtype)
    target = jnp.asarray([[4.0, 2.0, 3.0], [1.0, 2.0, 3.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], dtype)
    pose, valid = f(eye, target)
    assert np.asarray(valid).tolist() == [True, False, False, False]
    assert bool(jnp.all(jnp.isfinite(pose)))
    # Even the stand-in poses are rigid transforms, and the valid one is the default output.
    for k in range(4):
        R = np.asarray(pose[k, :3, :3], np.float64)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-5)
    np.testing.assert_allclose(pose[0], jax.jit(q.look_at)(eye[0], target[0]), rtol=1e-6)
    with pytest.raises(ValueError, match="target: must differ from eye"):
        q.look_at(np.asarray(eye[1]), np.asarray(target[1]), with_valid=True)


def test_look_at_with_a_tiny_float32_baseline_is_still_a_rotation():
    # Regression: the view direction was divided by max(|d|, 8 eps), not unit for |d| < 1e-6.
    T = q.look_at(np.zeros(3, np.float32), np.array([1e-7, 0.0, 0.0], np.float32))
    R = np.asarray(T[:3, :3], np.float64)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-5)


def test_rasterize_footprint_reports_the_object_it_cannot_draw():
    R = jnp.stack([jnp.eye(3)] * 3)
    c = jnp.asarray([[1.0, 1.0, 0.0], [_NAN, 1.0, 0.0], [2.0, 2.0, 0.0]])
    r = jnp.asarray([[0.5, 0.5, 0.5], [0.5, 0.5, 0.5], [0.5, -0.5, 0.5]])
    f = jax.jit(
        lambda R, c, r: q.rasterize_footprint(R, c, r, jnp.array([1, 2, 3]), (8, 8), jnp.zeros(2), 0.5, with_valid=True)
    )
    grid, valid = f(R, c, r)
    assert np.asarray(valid).tolist() == [True, False, False]
    assert set(np.unique(np.asarray(grid)).tolist()) == {0, 1}  # the two bad objects are not drawn
    # The default output is the grid alone, as before.
    np.testing.assert_array_equal(
        jax.jit(lambda R, c, r: q.rasterize_footprint(R, c, r, 1, (8, 8), jnp.zeros(2), 0.5))(R[:1], c[:1], r[:1]),
        grid > 0,
    )


# --------------------------------------------------------------------------------------------
# Item 2: float32 and float64 agree on valid views (the conic route).


def _valid_views(n, seed):
    """Random views that are valid by construction: the ellipsoid's bounding sphere lies at least
    half a metre in front of the camera and its centre inside a 100-degree field of view."""
    rng = np.random.default_rng(seed)
    R = np.asarray(q.random_rotation(jax.random.PRNGKey(seed), (n,), dtype=jnp.float64))
    radii = rng.uniform(0.02, 3.0, (n, 3))
    cam_R = np.asarray(q.random_rotation(jax.random.PRNGKey(seed + 1), (n,), dtype=jnp.float64))
    cam_t = rng.normal(scale=20.0, size=(n, 3))
    depth = rng.uniform(0.5, 80.0, n) + np.linalg.norm(radii, axis=-1)
    center_cam = np.column_stack([rng.uniform(-1.2, 1.2, (n, 2)) * depth[:, None], depth])
    center = np.einsum("nji,nj->ni", cam_R, center_cam - cam_t)
    T = np.zeros((n, 4, 4))
    T[:, :3, :3], T[:, :3, 3], T[:, 3, 3] = cam_R, cam_t, 1.0
    f = rng.uniform(200.0, 3000.0, n)
    K = np.zeros((n, 3, 3))
    K[:, 0, 0], K[:, 1, 1], K[:, 2, 2] = f, f * rng.uniform(0.9, 1.1, n), 1.0
    K[:, 0, 1] = rng.uniform(-1.0, 1.0, n)
    K[:, 0, 2], K[:, 1, 2] = rng.uniform(0.0, 1000.0, n), rng.uniform(0.0, 800.0, n)
    return R, center, radii, K, T


_chain = jax.jit(_conic_chain)
_outline_jit = jax.jit(_outline)


def test_float32_conic_route_has_no_false_invalid_on_10000_valid_views():
    views = _valid_views(10_000, seed=26)
    _, ok64 = _chain(*views)
    assert bool(jnp.all(ok64))
    as32 = [x.astype(np.float32) for x in views]
    for name, route in (
        ("conic_bbox", _chain),
        ("conic_outline", _outline_jit),
        ("project_bbox", jax.jit(q.project_bbox)),
    ):
        _, ok32 = route(*as32)
        assert int(jnp.sum(~ok32)) == 0, f"{name}: {int(jnp.sum(~ok32))} false invalids in float32"


def test_float32_conic_route_jacfwd_is_finite():
    views = [x.astype(np.float32) for x in _valid_views(500, seed=27)]

    def scalar(R, c, r, K, T):
        box, _ = _conic_chain(R, c, r, K, T)
        pts, _ = _outline(R, c, r, K, T)
        return jnp.sum(box) + jnp.sum(pts)

    jac = jax.jit(jax.vmap(jax.jacfwd(scalar, argnums=(0, 1, 2, 3, 4))))(*views)
    for j in jac:
        assert bool(jnp.all(jnp.isfinite(j)))


# --------------------------------------------------------------------------------------------
# Bad inputs that looked valid under jit: none may come back finite with valid True. Each case
# is evaluated over random good contexts (views, ellipsoids) with the bad value put in.

_RNG = np.random.default_rng(45)
_VIEWS = _valid_views(8, seed=45)
_K_BOTTOM_ZERO = np.vstack([K0[:2], np.zeros((1, 3))])


def _bbox_with(arg, value):
    def f(R, c, r, K, T):
        args = {"rotation": R, "center": c, "radii": r, "K": K, "camera_T_world": T}
        args[arg] = jnp.broadcast_to(jnp.asarray(value, c.dtype), args[arg].shape)
        return args

    return f


def _chain_of(args):
    return _conic_chain(args["rotation"], args["center"], args["radii"], args["K"], args["camera_T_world"])


LOOKED_VALID = {
    "project_bbox-K-bottom-row-zero": lambda *v: q.project_bbox(**_bbox_with("K", _K_BOTTOM_ZERO)(*v)),
    "conic_chain-K-bottom-row-zero": lambda *v: _chain_of(_bbox_with("K", _K_BOTTOM_ZERO)(*v)),
    "camera_valid-K-bottom-row-zero": lambda R, c, r, K, T: (K, q.camera_valid(jnp.asarray(_K_BOTTOM_ZERO), T)),
    "project_points-K-bottom-row-zero": lambda R, c, r, K, T: q.project_points(
        c, jnp.asarray(_K_BOTTOM_ZERO, c.dtype), T, with_valid=True
    )[::2],
    "back_project-K-bottom-row-zero": lambda R, c, r, K, T: q.back_project(
        jnp.asarray([300.0, 200.0], c.dtype), 2.0, jnp.asarray(_K_BOTTOM_ZERO, c.dtype), T, with_valid=True
    ),
    "conic_chain-negative-radii": lambda R, c, r, K, T: _conic_chain(R, c, -r, K, T),
    "conic_chain-one-negative-radius": lambda R, c, r, K, T: _conic_chain(R, c, r * jnp.array([1.0, -1.0, 1.0]), K, T),
    "conic_chain-scaled-rotation": lambda R, c, r, K, T: _conic_chain(2.0 * R, c, r, K, T),
    "conic_outline-negative-radii": lambda R, c, r, K, T: _outline(R, c, -r, K, T),
    "rasterize_footprint-nan-centre": lambda R, c, r, K, T: _raster(R, c.at[0].set(jnp.nan), r, K, T),
    "look_at-eye-on-target": lambda R, c, r, K, T: q.look_at(c, c, with_valid=True),
    "quaternion_wxyz-zero": lambda R, c, r, K, T: q.quaternion_wxyz_to_rotation(jnp.zeros(4, c.dtype), with_valid=True),
    "quaternion_xyzw-zero": lambda R, c, r, K, T: q.quaternion_xyzw_to_rotation(jnp.zeros(4, c.dtype), with_valid=True),
    "quaternion-nan": lambda R, c, r, K, T: q.quaternion_wxyz_to_rotation(
        jnp.asarray([jnp.nan, 0.0, 0.0, 1.0], c.dtype), with_valid=True
    ),
    "nearest_rotation-reflection": lambda R, c, r, K, T: q.nearest_rotation(-R, with_valid=True),
    "nearest_rotation-zeros": lambda R, c, r, K, T: q.nearest_rotation(0.0 * R, with_valid=True),
    "depth_from_box_size-K-bottom-row-zero": lambda R, c, r, K, T: q.depth_from_box_size(
        jnp.asarray([300.0, 200.0, 340.0, 260.0], c.dtype), jnp.asarray(_K_BOTTOM_ZERO, c.dtype), T, r
    ),
}


@pytest.mark.parametrize("case", sorted(LOOKED_VALID))
def test_bad_input_under_jit_never_comes_back_finite_and_valid(case):
    f = jax.jit(jax.vmap(LOOKED_VALID[case]))
    value, valid = f(*(jnp.asarray(x) for x in _VIEWS))
    valid = np.asarray(valid).reshape(len(_VIEWS[0]), -1).all(-1)
    finite = np.asarray(jnp.isfinite(value)).reshape(len(_VIEWS[0]), -1).all(-1)
    assert not np.any(finite & valid), f"{case}: finite and valid in {int(np.sum(finite & valid))} of {len(valid)}"
