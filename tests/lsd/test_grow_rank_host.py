"""A grow's candidates ranked on the host (numba, ``rank_rows``) against the device's ranked
search (``_knn`` under jit): every row the host settles holds the device's candidates in the
device's order; rows whose order a rounding or a sector border could change are left to the
device, and only those."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsem.planning._neighbours import _candidates_host, _knn  # layers: white-box

EXTENT = (12.0, 12.0)
RADIUS = 1.0


def _device(p, ok, k, sectors, keep):
    """The device's ranked rows of every point (bucketed search, slots enough for every strip)."""
    pts = jnp.asarray(p)
    args = (pts, jnp.asarray(ok), pts, jnp.arange(len(p)), k, RADIUS, EXTENT, 128, sectors, keep)
    ranked, over = jax.jit(lambda: _knn(*args))()
    assert not bool(over)
    return np.where(ok[:, None], np.asarray(ranked), len(p))


def _counts(p, ok):
    """Each usable point's candidates within the radius, in float64 (an independent count)."""
    d = p[None].astype(np.float64) - p[:, None].astype(np.float64)
    near = (np.sum(d * d, -1) <= RADIUS**2) & ok[None, :] & ok[:, None]
    return near.sum(1) - ok


def _check(p, ok, k, sectors):
    keep = 2 * k if sectors else k
    want = _device(p, ok, k, sectors, keep)
    got, need, _ = _candidates_host(p, ok, np.arange(len(p)), k, RADIUS, EXTENT, keep, 128, sectors)
    many = _counts(p, ok) > k
    settled = ~need
    # Rows of at most k: the device's set; rows of more: the device's candidates in its order.
    assert all(set(a) == set(b) for a, b in zip(got[settled & ~many].tolist(), want[settled & ~many].tolist()))
    np.testing.assert_array_equal(got[settled & many], want[settled & many])
    assert np.all(got[need] == len(p))
    return many, need


@pytest.mark.parametrize("sectors,k", [(8, 6), (0, 9), (5, 9)])
def test_host_ranked_rows_are_the_devices(sectors, k):
    """Random float32 points, a few unusable, two on a diagonal of each other: the host settles
    nearly every row with more than k candidates (ties within a few units in the last place are
    rare), in the device's order; with eight sectors the two on a diagonal (a border, where
    either side may be the device's sector) are left to the device."""
    rng = np.random.default_rng(sectors * 100 + k)
    p = rng.uniform(0.0, EXTENT[0], (1200, 2)).astype(np.float32)
    p[11] = p[10] + np.float32(0.125)  # exactly on the diagonal: the nearest in its sector
    ok = np.ones(len(p), bool)
    ok[[3, 50]] = False
    many, need = _check(p, ok, k, sectors)
    assert many.sum() > 300 and many[10] and many[11]
    assert (many & need).sum() <= 0.05 * many.sum()
    assert need[10] == need[11] == (sectors == 8)


def test_ties_and_borders_are_left_to_the_device():
    """Points on a lattice of eighths: mirror images tie in distance, and directions along the
    axes and diagonals lie on sector borders. The host settles no row whose ranked candidates it
    cannot order for sure, and what it settles is the device's."""
    g = np.arange(0, 96) / 8
    p = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)[::7].astype(np.float32)
    ok = np.ones(len(p), bool)
    many, need = _check(p, ok, 6, 8)
    assert many.any() and np.all(need[many])  # every full row holds a tie


def _crowd(extra):
    """Point 0 at (6, 6) with generic neighbours all round (more than k = 4 within the radius),
    then ``extra`` (relative to point 0)."""
    rng = np.random.default_rng(7)
    ring = rng.uniform(0.55, 0.95, 10) * np.exp(1j * rng.uniform(0.0, 2 * np.pi, 10))
    rel = np.concatenate([np.stack([ring.real, ring.imag], -1), np.asarray(extra, np.float64)])
    rel = rel[np.abs(rel).min(1) > 0.05]  # keep every direction off the quadrants' borders
    return np.concatenate([[[6.0, 6.0]], 6.0 + rel]).astype(np.float32)


def _row_zero(p, k=4, sectors=4):
    many, need = _check(p, np.ones(len(p), bool), k, sectors)
    assert many[0]
    return need[0]


def test_a_tie_for_a_sectors_reserved_place_is_left_to_the_device():
    """Two candidates mirrored about a quadrant's bisector tie exactly in distance, and are that
    quadrant's nearest: which one the quadrant reserves is the device's slot order, so the row is
    the device's; moved apart, the same row is settled on the host."""
    tied = [[0.25, 0.5], [0.5, 0.25]]
    apart = [[0.25, 0.5], [0.5, 0.3]]
    assert _row_zero(_crowd(tied))
    assert not _row_zero(_crowd(apart))


def test_keys_that_round_together_are_left_to_the_device():
    """Two unreserved candidates whose squared distances differ by a few units in the last
    place (more than a rounding of the distances, less than one of the keys ``d2 + span``):
    their order is the device's rounding, so the row is the device's."""
    base = [[0.1, 0.12]]  # the quadrant's reserved (nearest) candidate
    a = np.float32(6.0) + np.float32([0.7, 0.1])
    b = np.float32(6.0) + np.float32([0.1, 0.7])
    for _ in range(64):  # step b outward until its distance exceeds a's by 5 to 40 units of 1e-7
        b[1] = np.nextafter(b[1], np.float32(9.0))
        da = np.sum(np.square(a - np.float32(6.0)))
        db = np.sum(np.square(b - np.float32(6.0)))
        if db - da > 5e-7 * 5:
            break
    assert 2e-6 < (db - da) / da < 8e-6
    near = np.stack([a, b]).astype(np.float64) - 6.0
    assert _row_zero(_crowd(np.concatenate([base, near])))
    near[1] += [0.0, 0.05]
    assert not _row_zero(_crowd(np.concatenate([base, near])))


def test_the_bucket_order_is_the_devices_from_a_right_or_a_wrong_guess():
    """The grow's bucket order on the device from the host's guess: the device's own sort's
    answer when the guess is right (points on bucket edges included), and when it is not."""
    from jaxsem.planning._lazy import _grid_jit  # layers: white-box
    from jaxsem.planning._neighbours import _host_order, _knn_grid  # layers: white-box

    rng = np.random.default_rng(5)
    p = rng.uniform(0.0, EXTENT[0], (700, 2)).astype(np.float32)
    p[:40] = np.round(p[:40])  # on bucket edges (radius 1)
    ok = rng.random(len(p)) > 0.05
    origin = jnp.zeros(2, jnp.float32)
    want = jax.jit(lambda: _knn_grid(jnp.asarray(p), jnp.asarray(ok) & (jnp.arange(len(p)) >= 2), RADIUS, EXTENT))()
    guess = _host_order(p, ok & (np.arange(len(p)) >= 2), RADIUS, EXTENT)
    for g in (guess, guess[::-1].copy(), np.roll(guess, 1)):
        got = _grid_jit(jnp.asarray(p), jnp.asarray(ok), origin, jnp.asarray(g), radius=RADIUS, extent=EXTENT)
        for a, b in zip(got, want, strict=True):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    np.testing.assert_array_equal(guess, np.asarray(want[0]))
