"""VoluMon training end to end (tiny config): overfitting, exact resume, refinement, data skips."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsem import quadrics
from jaxsem.models import allocentric_rotation, reconstruct
from jaxsem.volumon import get_config, make_batch, optimise_from_scratch, postopt, train_and_evaluate
from jaxsem.volumon._losses import primal_loss_per_sample  # layers: white-box
from jaxsem.volumon._refine import init_from_points  # layers: white-box
from jaxsem.volumon._synthetic import SceneConfig  # layers: white-box
from jaxsem.volumon._train import batch_indices  # layers: white-box


def _config():
    return get_config("dual", "tiny").replace(num_train=4, num_steps=30, checkpoint_every=10, learning_rate=3e-3)


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    workdir = tmp_path_factory.mktemp("full")
    return workdir, train_and_evaluate(_config(), workdir, progress=False)


@pytest.mark.slow
def test_overfits_a_handful_of_samples(uninterrupted):
    workdir, result = uninterrupted
    h = result["history"]
    assert sorted(h) == list(range(1, 31))
    assert h[30]["dual"] < h[1]["dual"] / 10, (h[1]["dual"], h[30]["dual"])
    assert all(np.isfinite(v["total"]) for v in h.values())
    lines = (workdir / "metrics.jsonl").read_text().splitlines()
    assert json.loads(lines[-1])["step"] == 30


@pytest.mark.slow
def test_resume_equals_uninterrupted(uninterrupted, tmp_path):
    _, full = uninterrupted
    cfg = _config()
    first = train_and_evaluate(cfg, tmp_path, stop_after=13, progress=False)  # killed after step 13
    assert sorted(first["history"]) == list(range(1, 14))
    second = train_and_evaluate(cfg, tmp_path, progress=False)  # resumes from the step-13 checkpoint
    assert sorted(second["history"]) == list(range(14, 31))
    merged = {**first["history"], **second["history"]}
    for step in range(1, 31):
        assert merged[step] == full["history"][step], step  # bit-for-bit, step for step
    for a, b in zip(jax.tree.leaves(second["state"]), jax.tree.leaves(full["state"])):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_data_order_is_a_function_of_step():
    cfg = _config().replace(num_train=10, batch_size=4)
    seen = np.concatenate([batch_indices(cfg, s) for s in range(5)])
    assert sorted(seen[:10].tolist()) == list(range(10))  # epoch 0 is a permutation
    np.testing.assert_array_equal(batch_indices(cfg, 3), batch_indices(cfg, 3))


def test_box_outside_image_and_invisible_object_are_skipped():
    scene = SceneConfig(height=48, width=64, focal=55.0, num_points=8, depth_range=(0.3, 0.32))
    b = make_batch(0, np.arange(8), scene, input_size=32)
    # depth 0.3 m with margins clamped: some boxes leave the image -> masked out, never NaN
    inside = (
        np.all(np.asarray(b["box_left"])[:, :2] >= -0.5, -1)
        & (np.asarray(b["box_left"])[:, 2] <= 63.5)
        & (np.asarray(b["box_left"])[:, 3] <= 47.5)
    )
    np.testing.assert_array_equal(np.asarray(b["sample_mask"]), inside)
    for k in ("local", "global", "points", "box_left", "box_right"):
        assert np.all(np.isfinite(np.asarray(b[k]))), k


def test_each_stereo_label_is_the_object_seen_from_its_own_camera():
    """Issue 45 item 13: ``box_left`` / ``box_right`` against the true object's box in each
    camera, the right one written out by hand (``baseline`` along the left camera's +x); a label
    made with the other camera's pose trains the dual loss on a wrong stereo pair. The batch of
    the test above (the same arguments: no new compile)."""
    scene = SceneConfig(height=48, width=64, focal=55.0, num_points=8, depth_range=(0.3, 0.32))
    b = make_batch(0, np.arange(8), scene, input_size=32)
    right = np.eye(4, dtype=np.float32)
    right[0, 3] = -scene.baseline
    args = (b["gt_rotation"], b["gt_center"], b["gt_half_extents"], b["gt_shape_id"], b["K"][0])
    project = jax.jit(quadrics.shape_bbox)  # one compile for both cameras (eager: 5 times slower)
    for key, pose in (("box_left", np.eye(4, dtype=np.float32)), ("box_right", right)):
        want, _ = project(*args, pose)
        np.testing.assert_allclose(b[key], want, atol=1e-3, err_msg=key)
    shift = np.asarray(b["box_left"])[:, 0] - np.asarray(b["box_right"])[:, 0]  # about f b / z
    np.testing.assert_allclose(shift, 55.0 * scene.baseline / np.asarray(b["gt_center"])[:, 2], rtol=0.3)


def _ellipsoid_batch(n=6):
    scene = SceneConfig(height=48, width=64, focal=55.0, classes=(1, 2), num_points=64, depth_range=(0.45, 0.8))
    b = make_batch(5, np.arange(n), scene, input_size=32)
    cfg = _config()
    recon = cfg.recon
    f64 = lambda k: jnp.asarray(b[k], jnp.float64)
    return b, f64, recon, cfg


@pytest.mark.slow
def test_postopt_improves_perturbed_truth():
    b, f64, recon, cfg = _ellipsoid_batch()
    # true free parameters of the (ellipsoid-shaped) objects, then a pose perturbation
    R, t, h = f64("gt_rotation"), f64("gt_center"), f64("gt_half_extents")
    order = jnp.argsort(h, -1)  # f's sizes increase along the axes: permute the object axes
    h_sorted = jnp.take_along_axis(h, order, -1)
    R_sorted = jnp.take_along_axis(R, jnp.broadcast_to(order[:, None, :], R.shape), -1)
    R_sorted = R_sorted * jnp.linalg.det(R_sorted)[:, None, None]  # keep a proper rotation (axis sign)
    d = 2 * h_sorted
    inc = jnp.diff(d, axis=-1, prepend=jnp.full((d.shape[0], 1), recon.eps_s))
    phi_d = jnp.log(inc / recon.alpha_y)
    q = quadrics.rotation_to_quaternion(allocentric_rotation(R_sorted, t))
    box = f64("box_left")
    uv = t @ f64("K")[0].T
    uv = uv[:, :2] / uv[:, 2:]
    s_uv = (uv - box[:, :2]) / (box[:, 2:] - box[:, :2])
    phi_uv = jnp.log(s_uv) - jnp.log1p(-s_uv)
    s = recon.baseline_focal / (recon.alpha_delta * t[:, 2])
    phi_z = jnp.log(s) - jnp.log1p(-s)
    phi_true = jnp.concatenate([phi_d, q, phi_uv, phi_z[:, None]], -1)
    ell = reconstruct(phi_true, box, f64("K"), recon)
    np.testing.assert_allclose(ell.center, t, atol=1e-9)
    np.testing.assert_allclose(ell.radii, h_sorted, atol=1e-9)
    phi0 = phi_true + jnp.asarray(np.random.default_rng(0).normal(0, 0.15, phi_true.shape)).at[:, :3].set(0.0)
    pts, pm = f64("points"), jnp.asarray(b["point_mask"])
    e0 = reconstruct(phi0, box, f64("K"), recon)
    phi1, e1, losses = postopt(phi0, box, f64("K"), pts, pm, recon, cfg.loss, num_steps=50)
    np.testing.assert_array_equal(phi1[:, :3], phi0[:, :3])  # size fixed
    assert np.all(np.asarray(losses[:, -1]) < np.asarray(losses[:, 0]))
    err0 = np.linalg.norm(np.asarray(e0.center - t), axis=-1)
    err1 = np.linalg.norm(np.asarray(e1.center - t), axis=-1)
    assert np.median(err1) < np.median(err0)


@pytest.mark.slow
def test_optimise_from_scratch_reduces_primal_loss():
    b, f64, recon, cfg = _ellipsoid_batch()
    pts, pm, box, K = f64("points"), jnp.asarray(b["point_mask"]), f64("box_left"), f64("K")
    phi0 = init_from_points(box, K, pts, pm, recon)
    e0 = reconstruct(phi0, box, K, recon)
    # the initial depth is the mean point depth
    zmean = np.array([np.asarray(pts[i, :, 2])[np.asarray(pm[i])].mean() for i in range(len(pm))])
    np.testing.assert_allclose(e0.center[:, 2], zmean, rtol=1e-4)
    phi, e1, losses = optimise_from_scratch(box, K, pts, pm, recon, cfg.loss, num_steps=100)
    l0, _ = primal_loss_per_sample(e0, pts, pm, cfg.loss)
    l1, _ = primal_loss_per_sample(e1, pts, pm, cfg.loss)
    assert np.all(np.asarray(l1) < np.asarray(l0))
    assert all(np.all(np.isfinite(np.asarray(x))) for x in e1)
    # a detection with an empty mask stays finite and keeps its initialisation
    pm_empty = pm.at[0].set(False)
    phi_e, e_e, _ = optimise_from_scratch(box, K, pts, pm_empty, recon, cfg.loss, num_steps=5)
    assert np.all(np.isfinite(np.asarray(phi_e)))
    with pytest.raises(ValueError, match="points"):
        optimise_from_scratch(box, K, pts[:2], pm, recon)


@pytest.mark.slow
def test_train_from_a_directory_end_to_end_with_exact_resume(tmp_path):
    """``config.data == "directory"``: batches from jaxsem.data's pipeline over a written dataset."""
    import jax

    from jaxsem.training import ConfigMismatchError
    from jaxsem.volumon import get_config, train_and_evaluate
    from jaxsem.volumon.data import volumon_batch_source, volumon_eval_batch, write_synthetic_dataset

    write_synthetic_dataset(tmp_path / "d", 8, seed=5, frames_per_scene=4, progress=False)
    data = tmp_path / "d" / "train"
    cfg = get_config("both", "tiny").replace(
        batch_size=4, num_steps=4, checkpoint_every=2, eval_every=0, num_eval=8, data="directory", data_dir=str(data)
    )
    sizes = cfg.data_sizes()
    batch_fn, n = volumon_batch_source(data, batch_size=4, seed=cfg.seed, **sizes)
    assert n >= 4
    ev = volumon_eval_batch(data, num=8, **sizes)
    full = train_and_evaluate(cfg, tmp_path / "a", batch_fn=batch_fn, eval_batch=ev, progress=False)
    assert full["eval"] is not None and np.isfinite(full["eval"]["median_center_error_m"])
    train_and_evaluate(cfg, tmp_path / "b", batch_fn=batch_fn, stop_after=2, progress=False)
    lines = []
    resumed = train_and_evaluate(
        cfg, tmp_path / "b", batch_fn=batch_fn, eval_batch=ev, progress=False, log=lines.append
    )
    assert "resumed from step 2" in lines
    same = jax.tree.map(lambda x, y: bool(np.array_equal(x, y)), full["state"]["params"], resumed["state"]["params"])
    assert all(jax.tree.leaves(same))
    # other data under the same workdir is refused; a directory run without batches is refused
    with pytest.raises(ConfigMismatchError, match="data_dir"):
        train_and_evaluate(cfg.replace(data_dir=str(tmp_path)), tmp_path / "a", batch_fn=batch_fn, progress=False)
    with pytest.raises(ValueError, match="batch_fn"):
        train_and_evaluate(cfg, tmp_path / "c", progress=False)
    with pytest.raises(ValueError, match="data: .* not a directory"):
        volumon_batch_source(tmp_path / "nope", batch_size=4, **sizes)


@pytest.mark.slow  # compiles a tiny VoluMon (about 20-70 s on 2 cores)
def test_predict_batch_reads_the_batch_the_network_reads():
    from jaxsem.volumon import make_predict_fn, predict_batch
    from jaxsem.volumon._train import init_state  # layers: white-box

    cfg = _config()
    state, model, _ = init_state(cfg)
    variables = {"params": state["params"], "batch_stats": state["batch_stats"]}
    b = make_batch(cfg.seed, np.arange(3), cfg.scene, cfg.model.input_size, cfg.model.global_padding, "train")
    _, ell, _ = predict_batch(model, cfg, variables, b)
    # the reference: the jitted predictor with the five inputs named one by one
    _, ref, _ = make_predict_fn(model, cfg)(variables, b["local"], b["global"], b["box_input"], b["K"], b["class_id"])
    for got, want in zip(ell, ref):
        np.testing.assert_array_equal(np.asarray(got), np.asarray(want))
    assert np.asarray(ell.center).shape == (3, 3)
    with pytest.raises(ValueError, match=r"batch: missing \['K'\]"):
        predict_batch(model, cfg, variables, {k: v for k, v in b.items() if k != "K"})
