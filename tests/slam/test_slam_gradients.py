"""Gradients through the batch solve (optimistix implicit adjoint) against finite differences."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsem import factors as F, quadrics as Q, slam

K = np.array([[525.0, 0.0, 320.0], [0.0, 525.0, 240.0], [0.0, 0.0, 1.0]])


def _few_views():
    """Three nearby views of one car (a forward-like, ill-posed setting where the prior matters)."""
    R = np.asarray(Q.quaternion_to_rotation(jnp.array([np.cos(0.2), 0.0, 0.0, np.sin(0.2)])))
    c = np.array([15.0, 2.0, 0.8])
    r = np.array([2.6, 0.95, 0.8])
    eyes = np.array([[0.0, 0.0, 1.5], [1.0, 0.1, 1.5], [2.0, 0.0, 1.5]])
    poses = np.asarray(Q.look_at(eyes, eyes + np.array([1.0, 0.0, 0.0])))
    box, _ = Q.project_bbox(R, c, r, K, poses)
    depth, _ = Q.texture_plane_depth(R, c, r, poses)
    problem = slam.make_problem(
        K, [640, 480], poses, np.asarray(box), [0, 1, 2], [0, 0, 0], ["car"], texture_depth=np.asarray(depth)
    )
    return problem, r


@pytest.mark.slow
def test_gradient_of_solved_shape_wrt_prior_mean_matches_finite_differences():
    problem, r_true = _few_views()
    mean0, sigma = F.shape_prior_table()
    car = F.class_index("car")

    def objective(car_mean):
        mean = mean0.at[car].set(car_mean)
        cfg = slam.SolverConfig(shape_prior_mean=mean, shape_prior_sigma=sigma, max_steps=200, rtol=1e-13, atol=1e-13)
        est, info = slam.solve_batch(problem, slam.initialize(problem, cfg), cfg, method="optimistix")
        return jnp.sum(jnp.square(est.radii[0] - r_true)), info

    x0 = mean0[car]
    eps = 1e-4
    steps = eps * jnp.eye(3)

    @jax.jit
    def run(x):
        (val, info), grad = jax.value_and_grad(objective, has_aux=True)(x)
        fd_vals = jax.vmap(lambda xx: objective(xx)[0])(jnp.concatenate([x + steps, x - steps]))
        return val, info, grad, fd_vals

    val, info, grad, fd_vals = run(x0)
    assert bool(info.success)
    fd = (fd_vals[:3] - fd_vals[3:]) / (2 * eps)
    assert np.all(np.isfinite(grad)) and np.abs(fd).max() > 1e-3
    np.testing.assert_allclose(grad, fd, rtol=2e-3, atol=1e-6)
