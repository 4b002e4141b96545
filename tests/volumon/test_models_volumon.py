"""VoluMon network, reconstruction f (eq. 5.7), multi-class head, torchvision converter."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsem import quadrics
from jaxsem.models import (
    MobileNetV2,
    ReconstructionConfig,
    VoluMonConfig,
    allocentric_rotation,
    block_layout,
    convert_torchvision_mobilenet_v2,
    expected_params,
    init_volumon,
    last_channel,
    make_divisible,
    ray_rotation,
    reconstruct,
    select_class_params,
)
from jaxsem.volumon import prepare_inputs

K = jnp.array([[110.0, 0, 63.5], [0, 110.0, 47.5], [0, 0, 1]])


def _phis(seed, n, scale=3.0):
    return jnp.asarray(np.random.default_rng(seed).normal(size=(n, 10)) * scale)


def _boxes(seed, n):
    rng = np.random.default_rng(seed)
    lo = rng.uniform(0, 90, (n, 2))
    return jnp.asarray(np.concatenate([lo, lo + rng.uniform(1, 40, (n, 2))], -1))


def test_centroid_projects_inside_box_and_sizes_increase():
    phi, box = _phis(0, 200), _boxes(1, 200)
    for cfg in (ReconstructionConfig(), ReconstructionConfig(depth_mode="absolute", max_depth=50.0)):
        ell = jax.jit(lambda p, b: reconstruct(p, b, K, cfg))(phi, box)
        uvw = ell.center @ np.asarray(K).T
        uv = uvw[:, :2] / uvw[:, 2:]
        assert np.all(uvw[:, 2] > 0)
        assert np.all(uv >= box[:, :2] - 1e-9) and np.all(uv <= box[:, 2:] + 1e-9)
        d = np.asarray(ell.sizes)
        assert np.all(d >= cfg.eps_s) and np.all(np.diff(d, axis=-1) >= 0)
        R = np.asarray(ell.rotation)
        np.testing.assert_allclose(R @ np.swapaxes(R, -1, -2), np.broadcast_to(np.eye(3), R.shape), atol=1e-10)
        np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-10)


def test_depth_parameterisations():
    phi = jnp.zeros((1, 10)).at[0, 9].set(0.7)
    cfg = ReconstructionConfig(baseline_focal=6.6, alpha_delta=30.0)
    ell = reconstruct(phi, jnp.array([[60.0, 40, 70, 50]]), K, cfg)
    np.testing.assert_allclose(ell.center[0, 2], 6.6 / (30.0 * jax.nn.sigmoid(0.7)), rtol=1e-12)
    cfg = ReconstructionConfig(depth_mode="absolute", min_depth=0.5, max_depth=50.0)
    ell = reconstruct(phi, jnp.array([[60.0, 40, 70, 50]]), K, cfg)
    np.testing.assert_allclose(ell.center[0, 2], 0.5 + 49.5 * jax.nn.sigmoid(0.7), rtol=1e-12)
    # sizes: alpha_y cumsum(exp) + eps_s
    np.testing.assert_allclose(ell.sizes[0], 0.1 * np.array([1, 2, 3]) + 0.03, rtol=1e-12)
    with pytest.raises(ValueError, match="depth_mode"):
        ReconstructionConfig(depth_mode="metric")


def test_a_reference_focal_makes_what_looks_the_same_through_a_longer_lens_lie_farther():
    # Free parameters read from how an object looks: through a focal length s times as long the same
    # look means an object s times as far (same size). With the reference camera's focal length the
    # reconstruction says so: its projected box (the core's project_bbox) is the one through the
    # reference camera, up to perspective; as given (no reference), the box grows s times.
    rng = np.random.default_rng(3)
    n = 64
    phi = np.concatenate(
        [rng.normal(-1, 0.3, (n, 3)), rng.normal(size=(n, 4)), rng.normal(0, 1, (n, 2)), rng.normal(-1.5, 0.3, (n, 1))],
        -1,
    )
    lo = rng.uniform(20, 70, (n, 2))
    box = np.concatenate([lo, lo + rng.uniform(4, 12, (n, 2))], -1)
    ref, plain = ReconstructionConfig(reference_focal=110.0), ReconstructionConfig()
    run = jax.jit(reconstruct, static_argnums=3)
    e0 = run(phi, box, K, ref)
    same = run(phi, box, K, plain)  # through the reference camera itself, nothing changes
    np.testing.assert_allclose(np.asarray(e0.center), np.asarray(same.center), rtol=1e-12)
    b0, _ = quadrics.project_bbox(e0.rotation, e0.center, e0.radii, K, jnp.eye(4))
    w0 = np.asarray(b0[:, 2:] - b0[:, :2])
    for s in (0.6, 1.7):
        Ks = K.at[0, 0].multiply(s).at[1, 1].multiply(s)
        e = run(phi, box, Ks, ref)
        b, _ = quadrics.project_bbox(e.rotation, e.center, e.radii, Ks, jnp.eye(4))
        assert np.max(np.abs(np.asarray(b - b0)) / np.concatenate([w0, w0], -1)) < 0.15
        np.testing.assert_allclose(np.asarray(e.radii), np.asarray(e0.radii))
        p = run(phi, box, Ks, plain)
        bp, _ = quadrics.project_bbox(p.rotation, p.center, p.radii, Ks, jnp.eye(4))
        assert abs(np.median(np.asarray(bp[:, 2:] - bp[:, :2]) / w0) / s - 1) < 0.05
    for bad in (-1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="reference_focal"):
            ReconstructionConfig(reference_focal=bad)


def test_egocentric_equals_allocentric_for_centred_object():
    rng = np.random.default_rng(2)
    q = rng.normal(size=(5, 4))
    phi = jnp.zeros((5, 10)).at[:, 3:7].set(q).at[:, 7:9].set(0.0)
    # box centred on the principal point, so sigmoid(0) = 0.5 puts the centroid on the optical axis
    box = jnp.broadcast_to(jnp.array([53.5, 37.5, 73.5, 57.5]), (5, 4))
    ell = reconstruct(phi, box, K)
    np.testing.assert_allclose(ell.center[:, :2], 0.0, atol=1e-12)
    np.testing.assert_allclose(ell.rotation, quadrics.quaternion_to_rotation(jnp.asarray(q)), atol=1e-12)


def test_ray_rotation_and_allocentric_inverse():
    rng = np.random.default_rng(3)
    d = rng.normal(size=(20, 3))
    d[:, 2] = np.abs(d[:, 2]) + 0.1
    R = np.asarray(jax.jit(ray_rotation)(jnp.asarray(d)))
    n = d / np.linalg.norm(d, axis=-1, keepdims=True)
    np.testing.assert_allclose(R[:, :, 2], n, atol=1e-12)  # takes e_z to the ray
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    # the smallest rotation: its axis is perpendicular to both e_z and the ray
    phi, box = _phis(4, 20), _boxes(5, 20)
    allo = jax.jit(lambda p, b: allocentric_rotation(*reconstruct(p, b, K)[:2]))(phi, box)
    np.testing.assert_allclose(allo, quadrics.quaternion_to_rotation(phi[:, 3:7]), atol=1e-10)
    np.testing.assert_allclose(ray_rotation(jnp.zeros(3)), np.eye(3))


def test_reconstruct_no_nan_extremes_and_grad():
    phi = jnp.array([[80.0, -80, 0, 0, 0, 0, 0, 200, -200, -200.0], [0.0] * 10])  # zero quaternion too
    box = jnp.array([[10.0, 10, 10, 10], [5.0, 5, 6, 6]])  # zero-size box
    total = lambda p, b, k: jnp.sum(jnp.concatenate([x.reshape(-1) for x in reconstruct(p, b, k)]))
    f = jax.jit(jax.value_and_grad(total))
    for dtype in (jnp.float32, jnp.float64):
        val, g = f(phi.astype(dtype), box.astype(dtype), K.astype(dtype))
        assert np.isfinite(val) and np.all(np.isfinite(g)) and g.dtype == dtype
    with pytest.raises(ValueError, match="phi"):
        reconstruct(jnp.zeros((2, 9)), box, K)
    with pytest.raises(ValueError, match="box"):
        reconstruct(jnp.zeros((2, 10)), jnp.zeros((2, 3)), K)


def test_multiclass_selection_and_expectation():
    rng = np.random.default_rng(6)
    phi = jnp.asarray(rng.normal(size=(4, 3, 10)))
    cls = jnp.array([2, 0, 1, 2])
    np.testing.assert_allclose(select_class_params(phi, cls), np.asarray(phi)[np.arange(4), np.asarray(cls)])
    logits = jnp.asarray(rng.normal(size=(4, 3)))
    p = np.exp(logits) / np.exp(logits).sum(-1, keepdims=True)
    np.testing.assert_allclose(expected_params(phi, logits), np.einsum("bn,bnk->bk", p, phi), rtol=1e-10)
    # a confident prediction makes the expectation the selected row
    sharp = 1e3 * jax.nn.one_hot(cls, 3)
    np.testing.assert_allclose(expected_params(phi, sharp), select_class_params(phi, cls), atol=1e-10)


@pytest.mark.slow
def test_network_shapes_multiclass_and_inputs():
    cfg = VoluMonConfig(input_size=32, hidden=(16,), num_classes=3, backbone="small_cnn")
    model, variables = init_volumon(jax.random.PRNGKey(0), cfg)
    rng = np.random.default_rng(7)
    image = rng.integers(0, 255, (96, 128, 3), dtype=np.uint8)
    boxes = np.array([[10.0, 20, 40, 60], [60, 10, 120, 90]])
    local, glob = prepare_inputs(image, boxes, size=32)
    assert local.shape == glob.shape == (2, 32, 32, 3) and local.dtype == jnp.float32
    out = jax.jit(model.apply)(variables, local, glob)
    assert out.phi.shape == (2, 3, 10) and out.class_logits.shape == (2, 3)
    # initial predictions are sensible: identity allocentric quaternion, centroid near the box centre
    ell = reconstruct(select_class_params(out.phi, jnp.array([0, 1])), jnp.asarray(boxes, jnp.float32), K)
    assert np.all(np.isfinite(ell.center))
    # the masked global image is zero far from the box
    assert float(jnp.abs(glob[0, :, -4:]).max()) == 0.0


def test_bad_image_and_box_inputs():
    img = np.zeros((96, 128, 3), np.uint8)
    with pytest.raises(ValueError, match="dtype"):
        prepare_inputs(img.astype(np.int32), np.array([[1.0, 1, 5, 5]]))
    with pytest.raises(ValueError, match=r"\(H, W, 3\)"):
        prepare_inputs(img[..., 0], np.array([[1.0, 1, 5, 5]]))
    with pytest.raises(ValueError, match="outside"):
        prepare_inputs(img, np.array([[100.0, 10, 140, 50]]))
    with pytest.raises(ValueError, match="u_max > u_min"):
        prepare_inputs(img, np.array([[10.0, 10, 10, 50]]))
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        prepare_inputs(img.astype(np.float32) + 2.0, np.array([[1.0, 1, 5, 5]]))


def test_mobilenet_channel_rounding_like_torchvision():
    assert make_divisible(32 * 0.35) == 16 and make_divisible(16 * 0.35) == 8
    assert last_channel(0.35) == 1280 and last_channel(1.4) == 1792
    assert len(block_layout(1.0)) == 17 and block_layout(1.0)[-1][:2] == (160, 320)


# ---------------------------------------------------------------------------------------------
# torchvision converter, against an independent numpy forward pass of the raw state dict


def _torchvision_state_dict(width, rng):
    sd = {}

    def conv(key, cout, cin_per_group, k):
        sd[key + ".weight"] = rng.normal(0, 0.3, (cout, cin_per_group, k, k)).astype(np.float32)

    def bn(key, c):
        sd[key + ".weight"] = rng.uniform(0.5, 1.5, c).astype(np.float32)
        sd[key + ".bias"] = rng.normal(0, 0.1, c).astype(np.float32)
        sd[key + ".running_mean"] = rng.normal(0, 0.1, c).astype(np.float32)
        sd[key + ".running_var"] = rng.uniform(0.5, 2.0, c).astype(np.float32)
        sd[key + ".num_batches_tracked"] = np.array(7)

    c0 = make_divisible(32 * width)
    conv("features.0.0", c0, 3, 3)
    bn("features.0.1", c0)
    for i, (cin, cout, _, t) in enumerate(block_layout(width)):
        pre = f"features.{i + 1}.conv"
        hid = int(round(cin * t))
        j = 0
        if t != 1:
            conv(f"{pre}.0.0", hid, cin, 1)
            bn(f"{pre}.0.1", hid)
            j = 1
        conv(f"{pre}.{j}.0", hid, 1, 3)
        bn(f"{pre}.{j}.1", hid)
        conv(f"{pre}.{j + 1}", cout, hid, 1)
        bn(f"{pre}.{j + 2}", cout)
    n = len(block_layout(width)) + 1
    conv(f"features.{n}.0", last_channel(width), block_layout(width)[-1][1], 1)
    bn(f"features.{n}.1", last_channel(width))
    sd["classifier.1.weight"] = np.zeros((1000, last_channel(width)), np.float32)
    return sd


def _np_conv(x, w, stride, groups):
    """NCHW conv with torch semantics (symmetric padding (k-1)/2), float64."""
    N, C, H, W = x.shape
    O, Cg, k, _ = w.shape
    p = (k - 1) // 2
    xp = np.pad(x, ((0, 0), (0, 0), (p, p), (p, p)))
    Ho, Wo = (H + 2 * p - k) // stride + 1, (W + 2 * p - k) // stride + 1
    win = np.lib.stride_tricks.sliding_window_view(xp, (k, k), axis=(2, 3))[:, :, ::stride, ::stride][:, :, :Ho, :Wo]
    out = np.zeros((N, O, Ho, Wo))
    og = O // groups
    for g in range(groups):
        xs = win[:, g * Cg : (g + 1) * Cg]  # N, Cg, Ho, Wo, k, k
        ws = w[g * og : (g + 1) * og]  # og, Cg, k, k
        out[:, g * og : (g + 1) * og] = np.einsum("nchwij,ocij->nohw", xs, ws)
    return out


def _np_bn(x, sd, key):
    s = lambda n: sd[f"{key}.{n}"].astype(np.float64)[None, :, None, None]
    return (x - s("running_mean")) / np.sqrt(s("running_var") + 1e-5) * s("weight") + s("bias")


def _np_forward(sd, x, width):
    relu6 = lambda v: np.clip(v, 0, 6)
    w = lambda k: sd[k + ".weight"].astype(np.float64)
    y = relu6(_np_bn(_np_conv(x, w("features.0.0"), 2, 1), sd, "features.0.1"))
    for i, (cin, cout, s, t) in enumerate(block_layout(width)):
        pre = f"features.{i + 1}.conv"
        h = y
        j = 0
        if t != 1:
            h = relu6(_np_bn(_np_conv(h, w(f"{pre}.0.0"), 1, 1), sd, f"{pre}.0.1"))
            j = 1
        h = relu6(_np_bn(_np_conv(h, w(f"{pre}.{j}.0"), s, h.shape[1]), sd, f"{pre}.{j}.1"))
        h = _np_bn(_np_conv(h, w(f"{pre}.{j + 1}"), 1, 1), sd, f"{pre}.{j + 2}")
        y = y + h if (s == 1 and cin == cout) else h
    n = len(block_layout(width)) + 1
    y = relu6(_np_bn(_np_conv(y, w(f"features.{n}.0"), 1, 1), sd, f"features.{n}.1"))
    return y.mean(axis=(2, 3))


@pytest.mark.slow
def test_converter_matches_numpy_reference():
    width = 0.35
    rng = np.random.default_rng(8)
    sd = _torchvision_state_dict(width, rng)
    variables = convert_torchvision_mobilenet_v2(sd, width)
    x = rng.uniform(0, 1, (2, 3, 33, 33))  # odd size: exercises torch's symmetric stride-2 padding
    ref = _np_forward(sd, x, width)
    vx = jax.tree.map(lambda a: jnp.asarray(a, jnp.float64), variables)
    got = jax.jit(MobileNetV2(width).apply)(vx, jnp.asarray(np.transpose(x, (0, 2, 3, 1))))
    np.testing.assert_allclose(np.asarray(got), ref, rtol=1e-6, atol=1e-6 * np.abs(ref).max())
    # errors name the key
    bad = dict(sd)
    del bad["features.3.conv.1.1.running_var"]
    with pytest.raises(ValueError, match=r"features\.3\.conv\.1\.1\.running_var"):
        convert_torchvision_mobilenet_v2(bad, width)
    with pytest.raises(ValueError, match="shape"):
        convert_torchvision_mobilenet_v2(sd, 0.5)


def test_prepare_inputs_takes_the_trained_size_by_default():
    # Regression (architecture issue, friction 3): the default size was 64 while the shipped model
    # was trained at 48, so a user's crops silently had the wrong scale.
    from jaxsem.volumon import load_pretrained

    image = np.zeros((60, 80, 3), np.uint8)
    boxes = np.array([[10.0, 10, 40, 50]])
    _, _, config, _ = load_pretrained()
    local, glob = prepare_inputs(image, boxes)
    assert local.shape[1] == glob.shape[1] == config.model.input_size
    assert prepare_inputs(image, boxes, config=config)[0].shape[1] == config.model.input_size
    assert prepare_inputs(image, boxes, size=32)[0].shape[1] == 32
    with pytest.raises(ValueError, match="config"):
        prepare_inputs(image, boxes, config="volumon")
