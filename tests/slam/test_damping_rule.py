"""Issue 45 item 13: the Levenberg-Marquardt damping rule as a unit.

A rule that never lowers lambda still converges on the suite's small problems (only more
slowly), so the solver tests alone catch it by a hair. Here the rule itself: after an accepted
trial (a finite step that lowers the cost) the damping goes down, after a rejected one it goes
up, non-finite trials are rejected, the damping stays positive, and the search the solver runs
(:class:`DampingSearch`) keeps the damping on its first step and fails past ``lambda_max``. And the
damped step those trials take (:func:`damped_schur_step`) against the damped normal equations
solved densely: a step damped on the wrong blocks still converges to the same optimum. Last, a
whole solve: the damping it ends with follows from its accepted and rejected trial counts.
"""

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest

from jaxsem.slam import SchurLevenbergMarquardt
from jaxsem.slam._cost import Normal  # layers: white-box
from jaxsem.slam._schur import DampingSearch, SchurStructure, damped_schur_step, damping_search  # layers: white-box

LAMS = [1e-9, 1e-3, 1.0, 1e4]


@pytest.mark.parametrize("lam", LAMS)
def test_an_accepted_step_lowers_the_damping(lam):
    for cost, new in ((10.0, 9.0), (1.0, 1.0 - 1e-12), (5.0, 0.0)):
        accept, new_lam = damping_search(jnp.asarray(cost), jnp.asarray(new), jnp.asarray(lam), jnp.asarray(True))
        assert bool(accept)
        assert 0 < float(new_lam) < lam


@pytest.mark.parametrize("lam", LAMS)
def test_a_rejected_step_raises_the_damping(lam):
    cases = [
        (10.0, 11.0, True),  # higher cost
        (10.0, 10.0, True),  # no decrease
        (10.0, float("nan"), True),  # the trial's cost is NaN
        (10.0, float("inf"), True),
        (10.0, 1.0, False),  # lower, but the step itself was not finite
    ]
    for cost, new, finite in cases:
        accept, new_lam = damping_search(jnp.asarray(cost), jnp.asarray(new), jnp.asarray(lam), jnp.asarray(finite))
        assert not bool(accept), (cost, new, finite)
        assert float(new_lam) > lam, (cost, new, finite)


def test_the_damping_stays_positive_and_moves_both_ways():
    """Accepting many steps never drives the damping to zero; alternating accepts and rejects
    moves it down then up again (neither direction is a no-op)."""
    lam = jnp.asarray(1e-3)
    for _ in range(100):
        _, lam = damping_search(jnp.asarray(2.0), jnp.asarray(1.0), lam, jnp.asarray(True))
    assert float(lam) > 0
    lam = jnp.asarray(1e-3)
    seen = []
    for accept in (True, False, True, False):
        new = 1.0 if accept else 3.0
        _, lam = damping_search(jnp.asarray(2.0), jnp.asarray(new), lam, jnp.asarray(True))
        seen.append(float(lam))
    assert seen[0] < 1e-3 < seen[1] and seen[2] < seen[1] and seen[3] > seen[2]


def test_the_search_keeps_the_damping_on_its_first_step_and_fails_past_its_limit():
    search = DampingSearch(lambda_init=1e-2, lambda_max=1e3)
    state = search.init(jnp.zeros(3), None)
    assert float(state.lam) == pytest.approx(1e-2)
    cost = optx.FunctionInfo.Eval(jnp.asarray(2.0))
    lower, higher = optx.FunctionInfo.Eval(jnp.asarray(1.0)), optx.FunctionInfo.Eval(jnp.asarray(3.0))
    y = jnp.zeros(3)
    # the first step is always accepted, at the initial damping
    lam, accept, result, state = search.step(jnp.asarray(True), y, y, cost, higher, state)
    assert bool(accept) and float(lam) == pytest.approx(1e-2) and result == optx.RESULTS.successful
    # then the rule: down after an accepted trial, up after a rejected one
    lam_down, accept, _, down = search.step(jnp.asarray(False), y, y, cost, lower, state)
    assert bool(accept) and float(lam_down) < 1e-2 and float(down.lam) == float(lam_down)
    lam_up, accept, _, up = search.step(jnp.asarray(False), y, y, cost, higher, state)
    assert not bool(accept) and float(lam_up) > 1e-2 and float(up.lam) == float(lam_up)
    # rejected until the damping passes lambda_max: then the search fails
    results = []
    for _ in range(8):
        _, _, result, up = search.step(jnp.asarray(False), y, y, cost, higher, up)
        results.append(result == optx.RESULTS.successful)
        if not results[-1]:
            break
    assert not results[-1] and float(up.lam) > 1e3
    assert all(results[:-1])
    np.testing.assert_array_less(0.0, np.asarray(up.lam))


def _structured_system(seed, odometry, T=3, J=2, pairs=None):
    """Dense ``H = J^T J``, ``g = J^T r`` of a random Jacobian shaped like ROSHAN's (``T`` poses of
    6 columns, then ``J`` objects of 9; rows on one pose, on one object, on a pose and an object
    (every pose with every object, or the ``(pose, object)`` ``pairs``), and with ``odometry`` on
    consecutive poses), and the same system as block normal equations."""
    rng = np.random.default_rng(seed)
    pose = [np.arange(6 * t, 6 * t + 6) for t in range(T)]
    obj = [np.arange(6 * T + 9 * j, 6 * T + 9 * j + 9) for j in range(J)]
    if pairs is None:
        pairs = [(t, j) for t in range(T) for j in range(J)]
    groups = [[p] for p in pose] + [[o] for o in obj] + [[pose[t], obj[j]] for t, j in pairs]
    if odometry:
        groups += [[pose[t], pose[t + 1]] for t in range(T - 1)]
    rows = []
    for cols in groups:
        block = np.zeros((4, 6 * T + 9 * J))
        for c in cols:
            block[:, c] = rng.normal(size=(4, len(c)))
        rows.append(block)
    jac = np.concatenate(rows)
    H, g = jac.T @ jac, jac.T @ rng.normal(size=jac.shape[0])
    Hpp_next = None
    if odometry:
        Hpp_next = jnp.asarray(np.stack([H[np.ix_(pose[t], pose[t + 1])] for t in range(T - 1)] + [np.zeros((6, 6))]))
    normal = Normal(
        jnp.asarray(np.stack([H[np.ix_(p, p)] for p in pose])),
        jnp.asarray(np.stack([H[np.ix_(o, o)] for o in obj])),
        jnp.asarray(np.stack([np.stack([H[np.ix_(p, o)] for o in obj]) for p in pose])),
        jnp.asarray(np.stack([g[p] for p in pose])),
        jnp.asarray(np.stack([g[o] for o in obj])),
        jnp.asarray(0.0),
        Hpp_next,
    )
    return H, g, normal


@pytest.mark.parametrize(
    "odometry, pose_free, obj_free",
    [
        # 3 poses and 2 objects: 18 pose columns against 18 object ones, the objects eliminated
        (False, [1.0, 1.0, 1.0], [True, True]),
        (True, [1.0, 0.0, 1.0], [False, True]),
        # every pose held (the rescue phase): one small solve per object
        (False, [0.0, 0.0, 0.0], [True, True]),
        (True, [0.0, 0.0, 0.0], [True, False]),
        # 4 poses: 24 pose columns against 18, the poses eliminated
        (False, [1.0, 1.0, 0.0, 1.0], [True, True]),
        (True, [1.0, 0.0, 1.0, 1.0], [True, False]),
    ],
)
def test_the_damped_schur_step_solves_the_damped_dense_system(odometry, pose_free, obj_free):
    """The Schur step (poses or objects eliminated, per-block damping, held variables kept at
    zero) against ``(H + lam (diag(H) + 1e-9)) x = -g`` solved densely over the free variables."""
    H, g, normal = _structured_system(int(odometry), odometry, T=len(pose_free))
    lam = 0.3
    dp, do = jax.jit(damped_schur_step)(normal, lam, jnp.asarray(pose_free), jnp.asarray(obj_free))
    free = np.concatenate([np.repeat(np.asarray(pose_free) > 0, 6), np.repeat(obj_free, 9)])
    damped = H + lam * (np.diag(np.diag(H)) + 1e-9 * np.eye(len(g)))
    want = np.zeros(len(g))
    want[free] = np.linalg.solve(damped[np.ix_(free, free)], -g[free])
    got = np.concatenate([np.asarray(dp).ravel(), np.asarray(do).ravel()])
    np.testing.assert_allclose(got, want, rtol=1e-8, atol=1e-10 * np.max(np.abs(want)))
    # vmapped (the cond selects between both branches) it is the same step
    both = jax.jit(jax.vmap(damped_schur_step, in_axes=(None, None, 0, None)))(
        normal, lam, jnp.asarray([pose_free, pose_free]), jnp.asarray(obj_free)
    )
    np.testing.assert_allclose(np.asarray(both[1][1]), np.asarray(do), rtol=1e-12, atol=1e-14)
    # the damping matters here: the undamped step is another one
    undamped = np.linalg.solve(H[np.ix_(free, free)], -g[free])
    assert np.max(np.abs(undamped - want[free])) > 1e-3 * np.max(np.abs(want))


@pytest.mark.parametrize("odometry", [False, True])
def test_the_schur_step_from_the_pairs_blocks_equals_the_dense_one(odometry):
    """A long, sparse system (12 poses, 3 objects, 5 pose-object rows, one pair twice): the step
    that builds the reduced system from the rows' blocks solves the same damped system."""
    pairs = [(0, 0), (3, 1), (3, 1), (7, 2), (11, 0)]
    H, g, normal = _structured_system(5, odometry, T=12, J=3, pairs=pairs)
    pose_free, obj_free = np.ones(12), np.array([True, True, True])
    pose_free[5] = 0.0
    index = tuple(jnp.asarray(np.array(pairs)[:, k]) for k in range(2))
    lam = 0.01
    dp, do = jax.jit(damped_schur_step)(normal, lam, jnp.asarray(pose_free), jnp.asarray(obj_free), index)
    free = np.concatenate([np.repeat(pose_free > 0, 6), np.repeat(obj_free, 9)])
    damped = H + lam * (np.diag(np.diag(H)) + 1e-9 * np.eye(len(g)))
    want = np.zeros(len(g))
    want[free] = np.linalg.solve(damped[np.ix_(free, free)], -g[free])
    got = np.concatenate([np.asarray(dp).ravel(), np.asarray(do).ravel()])
    np.testing.assert_allclose(got, want, rtol=1e-8, atol=1e-10 * np.max(np.abs(want)))
    dense = jax.jit(damped_schur_step)(normal, lam, jnp.asarray(pose_free), jnp.asarray(obj_free))
    np.testing.assert_allclose(np.asarray(dense[1]), np.asarray(do), rtol=1e-10, atol=1e-12)


def _planar(y, args):
    """Three planar poses (x, y, theta) and two point landmarks: each landmark in each pose's
    frame against its measurement, pose priors and a weak landmark prior."""
    poses, landmarks = y
    p = poses[args["pose"]]
    c, s = jnp.cos(p[:, 2]), jnp.sin(p[:, 2])
    d = landmarks[args["landmark"]] - p[:, :2]
    local = jnp.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], -1)
    return (local - args["z"]) / 0.05, (poses - args["prior"]) / 0.1, 0.01 * (landmarks - args["l0"])


def test_the_solvers_damping_follows_its_accepted_and_rejected_trials():
    """Over a whole solve the damping the solver ends with is the initial one times 0.3 per
    accepted trial and 10 per rejected one (the counts the solver reports): the rule's update is
    carried from one iteration to the next, not reset."""
    rng = np.random.default_rng(0)
    pose_i, landmark_i = (x.ravel() for x in np.meshgrid(np.arange(3), np.arange(2), indexing="ij"))
    true_p = np.stack([np.arange(3.0), rng.normal(0, 0.3, 3), rng.normal(0, 0.2, 3)], -1)
    true_l = np.array([[0.5, 2.0], [2.0, 3.0]])
    c, s = np.cos(true_p[pose_i, 2]), np.sin(true_p[pose_i, 2])
    d = true_l[landmark_i] - true_p[pose_i, :2]
    z = np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], -1) + rng.normal(0, 0.02, d.shape)
    args = {"pose": pose_i, "landmark": landmark_i, "z": z, "prior": true_p + rng.normal(0, 0.05, true_p.shape)}
    args["l0"] = true_l + [3.0, -2.0]
    # headings 1.5 rad off the prior and landmarks 3.6 m off: far enough that some of the
    # undamped Gauss-Newton steps overshoot on any CPU's rounding (landmarks alone were not)
    y0 = (jnp.asarray(args["prior"] + [0.0, 0.0, 1.5]), jnp.asarray(args["l0"]))
    solver = SchurLevenbergMarquardt(
        1e-12, 1e-14, lambda a: SchurStructure(jnp.asarray(a["pose"]), jnp.asarray(a["landmark"])), lambda_init=1e-4
    )
    sol = optx.least_squares(_planar, solver, y0, args, throw=False)
    accepted, trials = int(sol.stats["accepted"]), int(sol.stats["trials"])
    assert accepted >= 3 and trials > accepted  # some steps down and some up
    want = 1e-4 * 0.3**accepted * 10.0 ** (trials - accepted)
    np.testing.assert_allclose(sol.state.search_state.lam, want, rtol=1e-9)
