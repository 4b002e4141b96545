"""Gradients through the batch solve (optimistix implicit adjoint) against finite differences."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsem import factors as F, slam
from jaxsem.slam._toy import few_views as _few_views  # layers: white-box


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

    # One traced solve: the value and gradient at x and at the six finite-difference points, one
    # after another (lax.map: each an unbatched solve); the other six gradients go unused.
    @jax.jit
    def run(x):
        points = jnp.concatenate([x[None], x + steps, x - steps])
        (vals, infos), grads = jax.lax.map(jax.value_and_grad(objective, has_aux=True), points)
        return vals[0], jax.tree_util.tree_map(lambda v: v[0], infos), grads[0], vals[1:]

    val, info, grad, fd_vals = run(x0)
    assert bool(info.success)
    fd = (fd_vals[:3] - fd_vals[3:]) / (2 * eps)
    assert np.all(np.isfinite(grad)) and np.abs(fd).max() > 1e-3
    np.testing.assert_allclose(grad, fd, rtol=2e-3, atol=1e-6)
