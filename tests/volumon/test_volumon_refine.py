"""VoluMon refinement (thesis 5.4.4, 5.5.1) on synthetic points: PostOpt at the truth, and the
primal loss's size weight on the one-sided point clouds of a box (the Table 5.1 regression)."""

import dataclasses

import jax.numpy as jnp
import numpy as np
import pytest

from jaxsem import quadrics
from jaxsem.models import allocentric_rotation, reconstruct
from jaxsem.volumon import LossConfig, get_config, make_batch, optimise_from_scratch, postopt
from jaxsem.volumon._losses import primal_loss_per_sample  # layers: white-box


def _batch(classes, n):
    cfg = get_config("primal", "cpu")
    scene = dataclasses.replace(cfg.scene, classes=classes)
    b = make_batch(3, np.arange(n), scene, cfg.model.input_size, cfg.model.global_padding, "test")
    return cfg, b


def _true_phi(b, recon):
    """Free parameters whose reconstruction f is the ground-truth object (its inscribed ellipsoid)."""
    R, t, h = (jnp.asarray(b[k], jnp.float32) for k in ("gt_rotation", "gt_center", "gt_half_extents"))
    order = jnp.argsort(h, -1)  # f's sizes increase along the axes: permute the object axes
    h = jnp.take_along_axis(h, order, -1)
    R = jnp.take_along_axis(R, jnp.broadcast_to(order[:, None, :], R.shape), -1)
    R = R * jnp.linalg.det(R)[:, None, None]  # a proper rotation (axis signs are free)
    d = 2 * h
    phi_d = jnp.log(jnp.diff(d, axis=-1, prepend=jnp.full((d.shape[0], 1), recon.eps_s)) / recon.alpha_y)
    q = quadrics.rotation_to_quaternion(allocentric_rotation(R, t))
    box, K = b["box_input"], b["K"]
    uv = jnp.einsum("bij,bj->bi", K, t)
    s_uv = (uv[:, :2] / uv[:, 2:] - box[:, :2]) / (box[:, 2:] - box[:, :2])
    s_z = recon.baseline_focal / (recon.alpha_delta * t[:, 2])
    logit = lambda s: jnp.log(s) - jnp.log1p(-s)
    phi = jnp.concatenate([phi_d, q, logit(s_uv), logit(s_z)[:, None]], -1)
    ell = reconstruct(phi, box, K, recon)
    np.testing.assert_allclose(ell.center, t, atol=1e-5)
    np.testing.assert_allclose(ell.radii, h, atol=1e-6)
    return phi


@pytest.mark.slow
def test_postopt_stays_at_the_truth_of_ellipsoid_objects():
    """Exact points of ellipsoid-shaped objects: the truth is the loss's zero, and PostOpt started
    there stays there (same frame for points, ellipsoid and metric). A small step size: Adam's
    first step is ``lr`` in every free parameter whatever the gradient, and at the thesis' 0.05
    that is ~3 cm of depth through the pseudo-disparity, enough to knock a few of these into the
    mirrored-cap local minimum of the algebraic error."""
    cfg, b = _batch((1, 2), 16)
    phi = _true_phi(b, cfg.recon)
    ell = reconstruct(phi, b["box_input"], b["K"], cfg.recon)
    per, has = primal_loss_per_sample(ell, b["points"], b["point_mask"], cfg.loss)
    assert np.all(np.asarray(has)) and float(jnp.max(per)) < 1e-5
    _, out, _ = postopt(
        phi, b["box_input"], b["K"], b["points"], b["point_mask"], cfg.recon, cfg.loss, num_steps=50, learning_rate=0.01
    )
    err = np.linalg.norm(np.asarray(out.center - b["gt_center"]), axis=-1)
    assert np.max(err) < 0.005, err


@pytest.mark.slow
def test_scratch_on_box_points_does_not_grow_and_recede():
    """Regression (Table 5.1: Scratch(500) translation AUC 0.48, below Scratch(50)'s 3.95): the
    visible faces of a box fit a large, distant ellipsoid better unless the size weight grows with
    size. With the default weight (Solina and Bajcsy's, the thesis' reference for the term) 500
    steps stay near the box; with eq. 5.12 read literally (power 0.5) they recede by decimetres."""
    cfg, b = _batch((0,), 16)
    args = (b["box_input"], b["K"], b["points"], b["point_mask"], cfg.recon)
    true_long = np.median(2 * np.max(np.asarray(b["gt_half_extents"]), -1))
    results = {}
    for power in (1.0, 0.5):
        loss = dataclasses.replace(cfg.loss, primal_size_power=power)
        _, out, _ = optimise_from_scratch(*args, loss, num_steps=500)
        err = np.median(np.linalg.norm(np.asarray(out.center - b["gt_center"]), axis=-1))
        long = np.median(np.max(np.asarray(out.sizes), -1))
        results[power] = (err, long)
    assert LossConfig().primal_size_power == 1.0
    err, long = results[1.0]
    assert err < 0.06 and long < 2.5 * true_long, results  # ~2.7 cm, 1.8x: an ellipsoid is not a box
    err, long = results[0.5]
    assert err > 0.15 and long > 3.0 * true_long, results  # ~35 cm, 4.4x: the literal reading recedes


@pytest.mark.slow
def test_postopt_from_the_truth_stays_there_with_the_class_shape():
    """Regression (issue 10): PostOpt drew every class as an ellipsoid, so a true cuboid or cylinder
    was not a zero of its objective and PostOpt moved it (median 0.9 cm, p90 3.5 cm on held-out
    detections; here, 12 cuboids: 2.9 cm drawn as ellipsoids, 0.2 cm with their shape)."""
    from jaxsem.models import ReconstructionConfig
    from jaxsem.volumon import LossConfig, held_out_set, postopt
    from jaxsem.volumon._refine import phi_from_ellipsoid  # layers: white-box
    from jaxsem.volumon._synthetic import SceneConfig  # layers: white-box

    scene = SceneConfig()
    b = held_out_set(7, 12, scene, 32, 0.1)
    recon = ReconstructionConfig(depth_mode="disparity", baseline_focal=scene.baseline * scene.focal)
    loss = LossConfig(shape_aware=True, primal_distance="ray")
    phi = phi_from_ellipsoid(
        quadrics.Ellipsoid(b["gt_rotation"], b["gt_center"], b["gt_half_extents"]), b["box_input"], b["K"], recon
    )
    args = (phi, b["box_input"], b["K"], b["points"], b["point_mask"], recon, loss, 50)
    _, ell, _ = postopt(*args, shape=b["class_shape"])
    drift = np.linalg.norm(np.asarray(ell.center) - np.asarray(b["gt_center"]), axis=-1)
    assert np.all(np.isfinite(drift)) and np.median(drift) < 5e-3
    _, ell_e, _ = postopt(*args)  # every class drawn as an ellipsoid: the cuboids move
    drift_e = np.linalg.norm(np.asarray(ell_e.center) - np.asarray(b["gt_center"]), axis=-1)
    assert np.median(drift_e) > 4 * np.median(drift)
    with pytest.raises(ValueError, match="shape"):
        postopt(*args, shape=b["class_shape"][:3])
