"""embed_local_distribution's outside_mass variant and NavConfig.outside_mass."""

import jax.numpy as jnp
import numpy as np
import pytest

from jaxsem.planning import NavConfig, Trial, embed_local_distribution, generate_building


def _window_mask(center, k, shape):
    mask = np.zeros(shape, bool)
    r0, c0 = center[0] - k // 2, center[1] - k // 2
    mask[max(r0, 0) : max(r0 + k, 0), max(c0, 0) : max(c0 + k, 0)] = True
    return mask


@pytest.mark.parametrize("center", [(20, 30), (2, 57)])
def test_outside_mass_share_and_window_proportions(center):
    rng = np.random.default_rng(0)
    k, shape = 16, (40, 60)
    local = rng.random((k, k)) + 0.01
    local /= local.sum()
    thesis = np.asarray(embed_local_distribution(jnp.asarray(local), jnp.asarray(center), shape))
    got = np.asarray(embed_local_distribution(jnp.asarray(local), jnp.asarray(center), shape, 0.3))
    inside = _window_mask(center, k, shape)
    np.testing.assert_allclose(got.sum(), 1.0, rtol=1e-6)
    np.testing.assert_allclose(got[~inside].sum(), 0.3, rtol=1e-6)
    assert np.ptp(got[~inside]) < 1e-9  # spread evenly
    # Inside the window the cells keep the thesis' proportions.
    np.testing.assert_allclose(got[inside] / got[inside].sum(), thesis[inside] / thesis[inside].sum(), rtol=1e-5)
    # q = 0: nothing outside.
    zero = np.asarray(embed_local_distribution(jnp.asarray(local), jnp.asarray(center), shape, 0.0))
    assert zero[~inside].max() == 0.0 and np.isclose(zero.sum(), 1.0)


def test_outside_mass_whole_map_window_and_bad_values():
    local = jnp.full((16, 16), 1.0 / 256)
    got = np.asarray(embed_local_distribution(local, jnp.asarray([5, 5]), (10, 10), 0.5))
    np.testing.assert_allclose(got, np.full((10, 10), 0.01), rtol=1e-6)  # no cell outside: q unused
    assert np.all(np.isfinite(got))
    with pytest.raises(ValueError, match="outside_mass"):
        embed_local_distribution(local, jnp.asarray([5, 5]), (10, 10), 1.0)
    b = generate_building(0, "test")
    free = b.free_cells(indoor=True)
    xy = b.origin + (free[len(free) // 2][::-1] + 0.5) * b.resolution
    with pytest.raises(ValueError, match="outside_mass"):
        Trial(b, xy, xy, None, NavConfig(outside_mass=(0.2,)))  # type: ignore[arg-type]
