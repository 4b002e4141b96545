"""LSD network (jaxsem.models): normalisation, loss, overfitting, bad input."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsem.models import (
    LSDConfig,
    init_lsd,
    lsd_distribution,
    lsd_nll,
    path_cells_to_mask,
)

K = 32  # small crops keep the compiles short; the network is size-agnostic
CFG = LSDConfig(map_size=K, features=(4, 8, 8), context_features=8)


def _maps(rng, batch):
    occ = rng.integers(-1, 2, batch + (K, K)).astype(np.int8)
    sem = rng.choice([0, 2, 3, 4], batch + (K, K), p=[0.9, 0.04, 0.03, 0.03]).astype(np.int8)
    return occ, sem


@pytest.fixture(scope="module")
def net():
    return init_lsd(jax.random.PRNGKey(0), CFG, jnp.float32)


@pytest.mark.slow
@pytest.mark.parametrize("dtype,batch", [(jnp.float32, ()), (jnp.float64, (3,)), (jnp.float32, (2, 1))])
def test_distribution_sums_to_one(net, dtype, batch):
    model, params = net
    params = jax.tree_util.tree_map(lambda p: p.astype(dtype), params)
    rng = np.random.default_rng(1)
    occ, sem = _maps(rng, batch)
    ctx = rng.normal(size=batch + (4,)).astype(dtype)
    for use_context in (True, False):
        p = lsd_distribution(model, params, occ, sem, ctx, use_context=use_context)
        assert p.shape == batch + (K, K) and p.dtype == dtype
        s = np.asarray(jnp.sum(p, axis=(-2, -1)), np.float64)
        np.testing.assert_allclose(s, 1.0, atol=1e-5 if dtype == jnp.float32 else 1e-12)
        assert np.all(np.asarray(p) > 0)


@pytest.mark.slow
def test_product_is_sum_in_log_space(net):
    model, params = net
    rng = np.random.default_rng(2)
    occ, sem = _maps(rng, (2,))
    ctx = rng.normal(size=(2, 4)).astype(np.float32)
    out = model.apply({"params": params}, occ, sem, ctx)
    ref = jax.nn.log_softmax((out.general + out.modifier).reshape(2, -1), -1).reshape(2, K, K)
    np.testing.assert_allclose(out.log_prob, ref, atol=1e-5)
    # The context changes the distribution only through the modifier.
    out2 = model.apply({"params": params}, occ, sem, ctx + 1.0)
    np.testing.assert_array_equal(out.general, out2.general)
    assert not np.allclose(out.modifier, out2.modifier)


def test_nll_matches_reference_and_skips_empty():
    rng = np.random.default_rng(3)
    logits = rng.normal(size=(3, 5, 5))
    lp = logits - np.log(np.exp(logits).sum((1, 2), keepdims=True))
    mask = np.zeros((3, 5, 5))
    mask[0, 1, 1] = mask[0, 2, 3] = 1
    mask[2, 4, 4] = 2  # a cell visited twice counts twice
    mask[2, 0, 0] = 1
    ref0 = -(lp[0, 1, 1] + lp[0, 2, 3]) / 2
    ref2 = -(2 * lp[2, 4, 4] + lp[2, 0, 0]) / 3
    np.testing.assert_allclose(lsd_nll(lp, mask), (ref0 + ref2) / 2, rtol=1e-12)
    g = jax.grad(lambda x: lsd_nll(x, np.zeros((3, 5, 5))))(jnp.asarray(lp))
    assert np.all(np.isfinite(g)) and float(lsd_nll(lp, np.zeros((3, 5, 5)))) == 0.0


def test_path_cells_to_mask_counts_and_padding():
    cells = np.array([[[1, 2], [1, 2], [0, 0], [-1, -1], [5, 40]]])
    m = np.asarray(path_cells_to_mask(cells, 8))
    assert m.shape == (1, 8, 8) and m[0, 1, 2] == 2 and m[0, 0, 0] == 1 and m.sum() == 3


@pytest.mark.slow
def test_nll_falls_when_overfitting_a_handful(net, optax_promotion):  # its own optax.adam loop
    model, params = net
    rng = np.random.default_rng(4)
    occ, sem = _maps(rng, (4,))
    ctx = rng.normal(size=(4, 4)).astype(np.float32)
    mask = np.zeros((4, K, K), bool)
    for i in range(4):  # a straight "path" per sample
        mask[i, K // 2, : K // 2 + 4 * i] = True
    import optax

    tx = optax.adam(1e-2)

    def loss(p):
        return lsd_nll(model.apply({"params": p}, occ, sem, ctx).log_prob, mask)

    @jax.jit
    def step(p, s):
        v, g = jax.value_and_grad(loss)(p)
        u, s = tx.update(g, s, p)
        return optax.apply_updates(p, u), s, v

    s = tx.init(params)
    first = float(loss(params))
    for _ in range(60):
        params, s, v = step(params, s)
    last = float(loss(params))
    assert np.isfinite(last)
    assert first > np.log(K * K) - 0.5  # starts near uniform
    assert last < first - 2.0, (first, last)


def test_bad_input_names_argument(net):
    model, params = net
    good = np.zeros((K, K), np.int8)
    ctx = np.zeros(4, np.float32)
    with pytest.raises(ValueError, match=r"occupancy: expected shape \(\.\.\., 32, 32\)"):
        model.apply({"params": params}, np.zeros((K, K + 1), np.int8), good, ctx)
    with pytest.raises(ValueError, match="semantic: expected an integer dtype"):
        model.apply({"params": params}, good, np.zeros((K, K), np.float32), ctx)
    with pytest.raises(ValueError, match=r"context: expected shape \(\.\.\., 4\), got shape \(3,\)"):
        model.apply({"params": params}, good, good, np.zeros(3, np.float32))
    with pytest.raises(ValueError, match="context: expected a floating dtype"):
        model.apply({"params": params}, good, good, np.zeros(4, np.int32))
    with pytest.raises(ValueError, match="batch shapes do not broadcast"):
        model.apply({"params": params}, np.zeros((2, K, K), np.int8), good, np.zeros((3, 4)))
    with pytest.raises(ValueError, match="map_size"):
        LSDConfig(map_size=30, features=(4, 8, 8))
    with pytest.raises(ValueError, match="path_mask: expected shape"):
        lsd_nll(np.zeros((2, K, K)), np.zeros((2, K)))


def test_jit_vmap_grad_finite(net):
    model, params = net
    rng = np.random.default_rng(5)
    occ, sem = _maps(rng, (2,))
    ctx = rng.normal(size=(2, 4)).astype(np.float32)
    f = jax.jit(jax.vmap(lambda o, s, c: lsd_distribution(model, params, o, s, c)))
    # The reference is the batched call, jitted whole (run op by op it compiled ~150 small programs).
    batched = jax.jit(lambda o, s, c: lsd_distribution(model, params, o, s, c))
    np.testing.assert_allclose(f(occ, sem, ctx), batched(occ, sem, ctx), atol=1e-6)
    g = jax.jit(jax.grad(lambda c: jnp.sum(lsd_distribution(model, params, occ, sem, c) ** 2)))(ctx)
    assert np.all(np.isfinite(g))


def _parity_spread(x):
    """Spread of the means of the four (row, col) parity classes of a 2-D map."""
    means = [float(np.mean(x[i::2, j::2])) for i in (0, 1) for j in (0, 1)]
    return max(means) - min(means)


def test_resize_upsampling_has_no_stripes():
    """The stripes of the distribution images are the transposed convolutions' parity pattern:
    on a constant input the 'transpose' network's output varies with cell parity, the 'resize'
    network's has (almost) none: what remains comes from the zero-padded borders."""
    cfg = dict(map_size=32, features=(4, 8), context_features=4)
    occ = jnp.zeros((1, 32, 32), jnp.int8)
    ctx = jnp.zeros((1, 4), jnp.float32)
    spread = {}
    for up in ("transpose", "resize"):
        model, params = init_lsd(jax.random.PRNGKey(1), LSDConfig(upsample=up, **cfg))
        out = jax.jit(model.apply)({"params": params}, occ, occ, ctx)
        inner = np.asarray(out.log_prob[0, 6:-6, 6:-6])
        spread[up] = _parity_spread(inner)
    assert spread["transpose"] > 1e-3
    assert spread["resize"] < 0.1 * spread["transpose"]


def test_log_range_bounds_the_spread():
    cfg = LSDConfig(map_size=32, features=(4, 8), context_features=4, log_range=3.0)
    model, params = init_lsd(jax.random.PRNGKey(2), cfg)
    params = jax.tree_util.tree_map(lambda p: 50.0 * p, params)  # a wildly confident network
    occ = jnp.asarray(np.random.default_rng(0).integers(-1, 2, (2, 32, 32)), jnp.int8)
    lp = np.asarray(jax.jit(model.apply)({"params": params}, occ, occ, jnp.ones((2, 4), jnp.float32)).log_prob)
    assert np.all(lp.max(axis=(1, 2)) - lp.min(axis=(1, 2)) <= 3.0 + 1e-5)
    with pytest.raises(ValueError, match="log_range"):
        LSDConfig(log_range=0.0)
    with pytest.raises(ValueError, match="upsample"):
        LSDConfig(upsample="bilinear")
