"""VoluMon on-device data, shape-aware losses, resume rules (issue 10)."""

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsem import quadrics
from jaxsem.models import Ellipsoid
from jaxsem.quadrics import shape_distance, stereo_right_T_left
from jaxsem.training import ConfigMismatchError
from jaxsem.volumon import (
    LossConfig,
    TrainConfig,
    get_config,
    held_out_set,
    make_train_step,
    train_and_evaluate,
)
from jaxsem.volumon._device_data import device_batch  # layers: white-box
from jaxsem.volumon._eval import size_errors  # layers: white-box
from jaxsem.volumon._losses import dual_loss_per_sample, primal_loss_per_sample  # layers: white-box
from jaxsem.volumon._synthetic import SceneConfig  # layers: white-box
from jaxsem.volumon._train import RESUMABLE_FIELDS, init_state  # layers: white-box

SCENE = SceneConfig(
    height=48,
    width=64,
    focal=55.0,
    classes=(0, 1, 2, 3),
    num_points=16,
    depth_range=(0.45, 0.8),
)
_batch = jax.jit(lambda key: device_batch(key, 8, SCENE, 32))


@pytest.fixture(scope="module")
def batch():
    return _batch(jax.random.PRNGKey(3))


def test_device_batch_deterministic_per_key(batch):
    again = _batch(jax.random.PRNGKey(3))
    for k in batch:
        np.testing.assert_array_equal(np.asarray(batch[k]), np.asarray(again[k]), err_msg=k)
    other = _batch(jax.random.PRNGKey(4))
    assert not np.allclose(np.asarray(other["gt_center"]), np.asarray(batch["gt_center"]))
    assert _batch._cache_size() == 1  # same shapes: one compilation for all keys


def test_device_batch_geometry(batch):
    b = {k: np.asarray(v) for k, v in batch.items()}
    assert set(b["gt_shape_id"].tolist()) <= {0, 1, 2}
    np.testing.assert_array_equal(b["class_shape"], b["gt_shape_id"])
    # rectified stereo: same rows, the right box shifted left by the disparity b f / z (+- the extent)
    np.testing.assert_allclose(b["box_left"][:, [1, 3]], b["box_right"][:, [1, 3]], atol=1e-3)
    disparity = 0.06 * 55.0 / b["gt_center"][:, 2]
    shift = 0.5 * (b["box_left"][:, 0] + b["box_left"][:, 2] - b["box_right"][:, 0] - b["box_right"][:, 2])
    np.testing.assert_allclose(shift, disparity, rtol=0.35)
    # surface points project inside the left box and lie on the object's surface
    uv, _ = quadrics.project_points(b["points"], b["K"][:, None], np.eye(4, dtype=b["points"].dtype)[None, None])
    m = b["point_mask"]
    uv = np.asarray(uv)
    assert np.all(uv[..., 0][m] >= b["box_left"][:, None, 0].repeat(16, 1)[m] - 1)
    assert np.all(uv[..., 0][m] <= b["box_left"][:, None, 2].repeat(16, 1)[m] + 1)
    d = np.asarray(
        shape_distance(
            b["points"],
            b["gt_rotation"],
            b["gt_center"],
            b["gt_half_extents"],
            b["gt_shape_id"],
        )
    )
    assert np.median(np.abs(d[m])) < 0.02


@pytest.mark.slow
def test_shape_aware_losses_zero_at_truth(batch):
    b = batch
    truth = Ellipsoid(b["gt_rotation"], b["gt_center"], b["gt_half_extents"])
    rtl = stereo_right_T_left(b["baseline"])
    aware = dual_loss_per_sample(
        truth,
        b["box_left"],
        b["box_right"],
        b["K"],
        rtl,
        LossConfig(),
        b["class_shape"],
    )
    thesis = dual_loss_per_sample(truth, b["box_left"], b["box_right"], b["K"], rtl, LossConfig())
    assert float(jnp.max(aware)) < 0.05  # pixels^2: the truth reproduces its own boxes
    boxes = np.asarray(b["gt_shape_id"]) != 1
    # an ellipsoid with the half extents of a box or can is too small for its boxes: the size bias
    assert float(jnp.min(thesis[boxes])) > 1.0
    cfg = LossConfig()
    per, _ = primal_loss_per_sample(truth, b["points"], b["point_mask"], cfg, b["class_shape"])
    per_thesis, _ = primal_loss_per_sample(truth, b["points"], b["point_mask"], cfg)
    assert float(jnp.mean(per)) < 0.2 * float(jnp.mean(per_thesis[boxes]))

    def dual_sum(r):
        e = truth._replace(radii=r)
        return jnp.sum(dual_loss_per_sample(e, b["box_left"], b["box_right"], b["K"], rtl, cfg, b["class_shape"]))

    g = jax.grad(dual_sum)(b["gt_half_extents"])
    assert np.all(np.isfinite(np.asarray(g)))


def test_shape_distance_finite_at_centre_and_float32():
    R = jnp.eye(3, dtype=jnp.float32)
    t = jnp.zeros(3, jnp.float32)
    r = jnp.array([0.1, 0.2, 0.3], jnp.float32)
    pts = jnp.array(
        [[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.1, 0.2, 0.3], [0.0, 0.0, 0.3]],
        jnp.float32,
    )
    # Jitted with the shape code an argument: one compile for the three shapes (run op by op, the
    # distance and its gradient compiled some 140 small programs).
    value_and_grad = jax.jit(
        lambda p, s: (shape_distance(p, R, t, r, s), jax.grad(lambda q: jnp.sum(shape_distance(q, R, t, r, s)))(p))
    )
    d = {}
    for shape in (0, 1, 2):
        d[shape], g = value_and_grad(pts, jnp.int32(shape))
        assert d[shape].dtype == jnp.float32
        assert np.all(np.isfinite(np.asarray(d[shape]))) and np.all(np.isfinite(np.asarray(g)))
        np.testing.assert_allclose(float(d[shape][0]), -1.0, atol=1e-3)
        np.testing.assert_allclose(float(d[shape][3]), 0.0, atol=1e-3)  # on every shape (a pole / cap / face)
    assert float(d[0][2]) < 0.2  # corner: on the cuboid
    assert float(d[1][2]) > 1.5  # far outside the ellipsoid


def test_size_metric_definition():
    true = np.array([[0.1, 0.2, 0.3], [0.05, 0.05, 0.05]])
    pred = np.array([[0.3, 0.1, 0.2], [0.1, 0.1, 0.1]])  # sorting: first object exact
    rel, _ = size_errors(pred, true)
    np.testing.assert_allclose(rel, [0.0, 1.0])
    _, const = size_errors(np.full_like(true, 0.1), true)
    assert const == 0.0


def _device_cfg():
    cfg = get_config("both", "tiny").replace(data="device", num_steps=6, checkpoint_every=3, log_every=1)
    return cfg.replace(
        scene=dataclasses.replace(cfg.scene, classes=(0, 1, 2, 3)),
        loss=dataclasses.replace(cfg.loss, shape_aware=True),
        model=dataclasses.replace(cfg.model, num_classes=4),
    )


@pytest.mark.slow
def test_device_train_step_no_recompiles():
    cfg = _device_cfg()
    state, model, tx = init_state(cfg)
    # the step train_and_evaluate makes for this config (run-length fields at their defaults):
    # test_resume_rules's fresh runs reuse its compilation (the module runs in one process)
    step = make_train_step(model, tx, cfg.replace(**{k: getattr(TrainConfig(), k) for k in RESUMABLE_FIELDS}))
    # jit caches are shared between wrappers of one function (and this step with the runs of
    # test_resume_rules), so an absolute cache size depends on which tests ran before: count what
    # the first step adds (at most one program) and what further steps add (nothing).
    before = step._cache_size()
    state, terms = step(state)
    compiled = step._cache_size()
    for _ in range(2):
        state, terms = step(state)
    assert int(state["step"]) == 3
    assert all(np.isfinite(float(v)) for v in terms.values())
    assert step._cache_size() == compiled <= before + 1


@pytest.mark.slow
def test_resume_rules(tmp_path):
    cfg = _device_cfg()
    lines = []
    full = train_and_evaluate(cfg, tmp_path / "full", progress=False)
    train_and_evaluate(cfg, tmp_path / "run", stop_after=4, progress=False)  # checkpoint at 3 and 4
    # a crash after the step-4 checkpoint but with rows written past it: they are cut back
    with open(tmp_path / "run" / "metrics.jsonl", "a") as f:
        f.write(json.dumps({"step": 5, "total": 1.0}) + "\n")
    res = train_and_evaluate(cfg, tmp_path / "run", progress=False, log=lines.append)
    assert "resumed from step 4" in lines
    steps = [json.loads(x)["step"] for x in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    assert steps == sorted(set(steps)) == list(range(1, 7))  # no duplicate rows
    for a, b in zip(jax.tree.leaves(res["state"]), jax.tree.leaves(full["state"])):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))  # still bit-exact
    with pytest.raises(ConfigMismatchError, match="learning_rate"):
        train_and_evaluate(
            cfg.replace(learning_rate=0.5, num_steps=8),
            tmp_path / "run",
            progress=False,
        )
    longer = train_and_evaluate(cfg.replace(num_steps=7), tmp_path / "run", progress=False)  # length may change
    assert int(longer["state"]["step"]) == 7
    forced = train_and_evaluate(
        cfg.replace(learning_rate=0.5, num_steps=8),
        tmp_path / "run",
        progress=False,
        force=True,
    )
    assert int(forced["state"]["step"]) == 8


@pytest.mark.slow
def test_held_out_set_is_deterministic_and_disjoint_from_training():
    a = held_out_set(5, 4, SCENE, 32, batch_size=4)
    b = held_out_set(5, 4, SCENE, 32, batch_size=4)
    np.testing.assert_array_equal(np.asarray(a["gt_center"]), np.asarray(b["gt_center"]))
    c = held_out_set(6, 4, SCENE, 32, batch_size=4)
    assert not np.allclose(np.asarray(a["gt_center"]), np.asarray(c["gt_center"]))
    with pytest.raises(ValueError, match="num"):
        held_out_set(5, 0, SCENE, 32)


def test_per_detection_scores_of_any_count_are_each_rows_own_and_share_one_program(compiles):
    # Scoring is per detection: a set's errors are its rows' errors alone, whatever the set's size,
    # and sets of other sizes (up to 16) reuse one compiled program.
    from jaxsem.volumon._eval import detection_errors  # layers: white-box

    rng = np.random.default_rng(0)

    def sample(n):
        R = np.linalg.qr(rng.normal(size=(n, 3, 3)))[0]
        R *= np.sign(np.linalg.det(R))[:, None, None]
        pred = {
            "rotation": R,
            "center": rng.normal(size=(n, 3)) * 0.1 + [0, 0, 1],
            "radii": rng.uniform(0.02, 0.1, (n, 3)),
        }
        gt = {
            "gt_rotation": R[::-1].copy(),
            "gt_center": pred["center"] + rng.normal(size=(n, 3)) * 0.01,
            "gt_half_extents": rng.uniform(0.02, 0.1, (n, 3)),
            "gt_shape_id": rng.integers(0, 3, n),
        }
        return pred, gt

    pred, gt = sample(5)
    whole = detection_errors(pred, gt)
    for i in range(5):
        one = detection_errors({k: v[i : i + 1] for k, v in pred.items()}, {k: v[i : i + 1] for k, v in gt.items()})
        for a, b in zip(whole, one):
            np.testing.assert_allclose(a[i], b[0], rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(whole[0], np.linalg.norm(pred["center"] - gt["gt_center"], axis=-1), rtol=1e-5)
    with compiles() as c:
        for n in (3, 11, 16):
            p, g = sample(n)
            assert all(len(x) == n and np.all(np.isfinite(x)) for x in detection_errors(p, g))
    assert c.count == 0
    assert all(len(x) == 0 for x in detection_errors(*sample(0)))
