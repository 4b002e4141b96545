"""jaxsem.checkpoint: round trip, keep-latest-N, missing / corrupt checkpoints name the path."""

import shutil

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from jaxsem.checkpoint import Checkpointer, CheckpointError, latest_step, restore_checkpoint, save_checkpoint


def _state(seed):
    rng = np.random.default_rng(seed)
    params = {"dense": {"kernel": jnp.asarray(rng.normal(size=(3, 4)), jnp.float32), "bias": jnp.zeros(4)}}
    opt_state = optax.adam(1e-3).init(params)
    return {
        "step": jnp.asarray(seed, jnp.int32),
        "params": params,
        "opt_state": opt_state,
        "rng": jax.random.PRNGKey(seed),
    }


def _assert_tree_equal(a, b):
    la, ta = jax.tree.flatten(a)
    lb, tb = jax.tree.flatten(b)
    assert ta == tb
    for x, y in zip(la, lb):
        assert np.asarray(x).dtype == np.asarray(y).dtype
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def test_round_trip_and_keep_latest(tmp_path):
    with Checkpointer(tmp_path / "ck", max_to_keep=2) as ckpt:
        assert ckpt.latest_step() is None
        for step in (1, 2, 3):
            assert ckpt.save(step, _state(step))
        assert ckpt.all_steps() == [2, 3]
        assert ckpt.latest_step() == 3
        restored = ckpt.restore(_state(0))
        _assert_tree_equal(restored, _state(3))
        _assert_tree_equal(ckpt.restore(_state(0), step=2), _state(2))
    # a fresh manager on the same folder sees the same steps
    assert latest_step(tmp_path / "ck") == 3
    _assert_tree_equal(restore_checkpoint(tmp_path / "ck", _state(0)), _state(3))


def test_save_interval_and_force(tmp_path):
    with Checkpointer(tmp_path, max_to_keep=None, save_interval_steps=5) as ckpt:
        assert not ckpt.save(3, _state(3))
        assert ckpt.save(5, _state(5))
        assert ckpt.save(7, _state(7), force=True)
        assert ckpt.all_steps() == [5, 7]


def test_missing_names_path(tmp_path):
    missing = tmp_path / "nowhere"
    with pytest.raises(CheckpointError, match="nowhere"):
        restore_checkpoint(missing, _state(0))
    assert latest_step(missing) is None
    save_checkpoint(tmp_path / "ck", 4, _state(4))
    with pytest.raises(CheckpointError, match=r"step 9 not found.*ck"):
        restore_checkpoint(tmp_path / "ck", _state(0), step=9)
    with pytest.raises(CheckpointError, match="no checkpoint"):
        Checkpointer(tmp_path / "empty").restore(_state(0))


def test_corrupt_names_path(tmp_path):
    save_checkpoint(tmp_path / "ck", 1, _state(1))
    step_dir = tmp_path / "ck" / "1"
    # wipe the array data but keep the folder: orbax still lists the step, reading fails
    for p in list(step_dir.rglob("*")):
        if p.is_file():
            p.write_bytes(b"garbage")
    with pytest.raises(CheckpointError, match=str(step_dir)):
        restore_checkpoint(tmp_path / "ck", _state(0))


def test_mismatched_target_names_path(tmp_path):
    save_checkpoint(tmp_path / "ck", 1, {"a": jnp.zeros(3)})
    with pytest.raises(CheckpointError, match="ck"):
        restore_checkpoint(tmp_path / "ck", {"b": jnp.zeros(3), "c": jnp.zeros(2)})


def test_bad_arguments(tmp_path):
    with pytest.raises(ValueError, match="max_to_keep"):
        Checkpointer(tmp_path, max_to_keep=0)
    f = tmp_path / "file"
    f.write_text("x")
    with pytest.raises(CheckpointError, match="file"):
        Checkpointer(f)
    shutil.rmtree(tmp_path / "ck", ignore_errors=True)


def test_a_restored_state_runs_the_jitted_step_it_was_saved_from_without_compiling(tmp_path, compiles):
    # A train state as a fresh run holds it: uncommitted arrays, and a Python number (weak-typed).
    params = {"w": jnp.ones((3,), jnp.float32)}
    state = {
        "params": params,
        "opt": optax.adam(1e-3).init(params),
        "step": jnp.asarray(0, jnp.int32),
        "lr": jnp.asarray(1e-3),
    }
    step = jax.jit(lambda s: jax.tree.map(lambda x: x + 1, s))
    state = step(state)
    with Checkpointer(tmp_path / "ck") as ckpt:
        ckpt.save(1, state)
        restored = ckpt.restore(state)
    _assert_tree_equal(restored, state)
    for a, b in zip(jax.tree.leaves(restored), jax.tree.leaves(state)):
        assert (a.dtype, a.weak_type, a.committed) == (b.dtype, b.weak_type, b.committed)
    with compiles() as c:
        jax.block_until_ready(step(restored))
    assert c.count == 0
