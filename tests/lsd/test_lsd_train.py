"""LSD training (jaxsem.lsd): two stages, frozen weights, checkpoint resume, sampler adapter."""

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from jaxsem import quadrics as Q
from jaxsem.lsd import LSDSampler, TrainConfig, full_map_distribution, load_trained, train_and_evaluate
from jaxsem.lsd._data import dihedral_augment, split_by_building  # layers: white-box
from jaxsem.lsd._train import save_distribution_figure  # layers: white-box
from jaxsem.models import LSDConfig, init_lsd, split_params

K = 32
# Transposed upsampling: the fine-tune tests start a resize network from these runs.
MODEL = LSDConfig(map_size=K, features=(4, 8, 8), context_features=8, upsample="transpose")


def _data(n=8, seed=0):
    """Synthetic expert samples: a corridor row; the path runs along it towards the goal side."""
    rng = np.random.default_rng(seed)
    occ = np.full((n, K, K), -1, np.int8)
    sem = np.zeros((n, K, K), np.int8)
    ctx = np.zeros((n, 4), np.float32)
    mask = np.zeros((n, K, K), bool)
    for i in range(n):
        r = rng.integers(8, K - 8)
        occ[i, r - 2] = occ[i, r + 2] = 1
        occ[i, r - 1 : r + 2] = 0
        sem[i, r - 2, rng.integers(K)] = 2
        right = i % 2 == 0
        ctx[i] = [1.0 if right else -1.0, 0.0, 0.5, 0.0]
        if right:
            mask[i, r, K // 2 :] = True
        else:
            mask[i, r, : K // 2 + 1] = True
    return {"occupancy": occ, "semantic": sem, "context": ctx, "path_mask": mask, "building_seed": np.arange(n) % 4}


CFG = TrainConfig(
    model=MODEL,
    stage1_steps=2,
    stage2_steps=2,
    batch_size=4,
    eval_every=100,
    checkpoint_every=2,
    num_figure_samples=2,
    learning_rate=1e-2,
    stage2_learning_rate=1e-2,
)


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    wd = tmp_path_factory.mktemp("lsd_a")
    res = train_and_evaluate(CFG, wd, data=_data(), progress=False)
    return wd, res


@pytest.mark.slow
def test_stage_two_leaves_encoder_decoder_bit_identical(run):
    wd, res = run
    _, after_stage1, _ = load_trained(wd, step=CFG.stage1_steps)
    gen1, cs1 = split_params(after_stage1)
    gen2, cs2 = split_params(res.params)
    assert gen1 and cs1
    for a, b in zip(jax.tree_util.tree_leaves(gen1), jax.tree_util.tree_leaves(gen2)):
        assert np.asarray(a).tobytes() == np.asarray(b).tobytes()
    changed = [not np.array_equal(a, b) for a, b in zip(jax.tree_util.tree_leaves(cs1), jax.tree_util.tree_leaves(cs2))]
    assert all(changed)
    # Stage one trains the encoder/decoder: they moved away from the initialisation.
    _, init = init_lsd(jax.random.PRNGKey(CFG.seed), MODEL)
    moved = [
        not np.array_equal(a, b)
        for a, b in zip(jax.tree_util.tree_leaves(split_params(init)[0]), jax.tree_util.tree_leaves(gen1))
    ]
    assert all(moved)
    # Evaluations wrote figures and metrics for both stages.
    assert [h["stage"] for h in res.history] == [1, 2]
    assert all((wd / "figures" / f"eval_{s:06d}.png").exists() for s in (2, 4))


@pytest.mark.slow
def test_resume_with_another_config_is_refused(run):
    wd, _ = run
    from jaxsem.training import ConfigMismatchError

    with pytest.raises(ConfigMismatchError, match="learning_rate: checkpoint 0.01, now 0.02"):
        train_and_evaluate(dataclasses.replace(CFG, learning_rate=2e-2), wd, data=_data(), progress=False)


@pytest.mark.slow
def test_checkpoint_resume_equals_uninterrupted(run, tmp_path):
    wd, res = run
    rows_before = [h["step"] for h in res.history]
    longer = dataclasses.replace(CFG, stage2_steps=4)
    lines = []
    resumed = train_and_evaluate(longer, wd, data=_data(), progress=False, log=lines.append)
    assert resumed.resumed_from == 4 and lines[0] == "resumed from step 4"
    # The resumed run's history continues the first chunk's rows, once each.
    assert [h["step"] for h in resumed.history] == rows_before + [6]
    fresh = train_and_evaluate(longer, tmp_path / "b", data=_data(), progress=False)
    assert fresh.resumed_from == 0
    for a, b in zip(jax.tree_util.tree_leaves(resumed.params), jax.tree_util.tree_leaves(fresh.params)):
        np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-7)
    _, restored, cfg = load_trained(wd)
    assert cfg.stage2_steps == 4
    for a, b in zip(jax.tree_util.tree_leaves(restored), jax.tree_util.tree_leaves(resumed.params)):
        np.testing.assert_array_equal(a, b)


def test_training_bad_input_names_the_argument(tmp_path):
    bad = _data()
    bad["path_mask"] = bad["path_mask"][:, :, :5]
    with pytest.raises(ValueError, match=r"data\['path_mask'\]: expected shape"):
        train_and_evaluate(CFG, tmp_path, data=bad, progress=False)
    with pytest.raises(ValueError, match="config: expected a jaxsem.lsd.TrainConfig"):
        train_and_evaluate({"lr": 1}, tmp_path, data=_data(), progress=False)
    with pytest.raises(ValueError, match="batch_size"):
        TrainConfig(batch_size=0)
    with pytest.raises(ValueError, match="workdir: no config.json"):
        load_trained(tmp_path / "nothing")


def test_split_by_building_holds_out_whole_buildings():
    d = _data(n=12)
    tr, va = split_by_building(d, 0.25, seed=0)
    assert len(tr) + len(va) == 12 and len(va) > 0
    assert not set(d["building_seed"][tr]) & set(d["building_seed"][va])


def test_dihedral_augment_keeps_goal_direction_consistent():
    # The path heads along the goal direction: after any flip/transpose it still does.
    d = _data(n=8)
    occ, sem, ctx, mask = dihedral_augment(
        jax.random.PRNGKey(3), d["occupancy"], d["semantic"], d["context"], d["path_mask"]
    )
    for i in range(8):
        r, c = np.nonzero(np.asarray(mask[i]))
        centre = (K - 1) / 2
        v = np.array([c.mean() - centre, r.mean() - centre])  # (x = cols, y = rows)
        assert v @ np.asarray(ctx[i, :2]) > 0
        assert int((np.asarray(occ[i]) == 1).sum()) == int((d["occupancy"][i] == 1).sum())


@pytest.mark.slow
def test_sampler_adapter_embedding_rule():
    from jaxsem.planning import FREE, MapState, embed_local_distribution, local_inputs

    model, params = init_lsd(jax.random.PRNGKey(1), MODEL)
    sampler = LSDSampler(model, params)
    H, W = 50, 70
    rng = np.random.default_rng(0)
    state = MapState(jnp.asarray(rng.integers(-1, 2, (H, W)), jnp.int8), jnp.zeros((H, W), jnp.int8))
    origin, res = np.zeros(2), 0.1
    xy, goal = np.array([2.05, 1.55]), np.array([6.0, 4.0])  # cell (row 15, col 20)
    grid = Q.Grid.host(origin, res, (H, W))
    full = full_map_distribution(sampler, state, xy, goal, False, grid)
    inputs = local_inputs(state, xy, goal, False, grid, K)
    local = np.asarray(sampler(inputs), np.float64)
    assert np.isclose(local.sum(), 1.0, atol=1e-5)
    np.testing.assert_array_equal(np.asarray(inputs.center_cell), [15, 20])
    # Independent reference of section 3.2.5: window where it lies on the map, the window's
    # minimum elsewhere, renormalised.
    ref = np.full((H, W), local.min())
    for i in range(K):
        for j in range(K):
            r, c = 15 - K // 2 + i, 20 - K // 2 + j
            if 0 <= r < H and 0 <= c < W:
                ref[r, c] = local[i, j]
    ref /= ref.sum()
    np.testing.assert_allclose(full, ref, rtol=1e-5)
    np.testing.assert_allclose(full.sum(), 1.0, rtol=1e-5)
    assert full.shape == (H, W) and np.all(full > 0)
    # The crop the network saw is the partial map around the robot (inside the map).
    np.testing.assert_array_equal(np.asarray(inputs.occupancy)[K // 2, K // 2], np.asarray(state.occupancy)[15, 20])
    # uniform_mix keeps a floor; context-free mode works too.
    mixed = LSDSampler(model, params, uniform_mix=0.5, use_context=False)(inputs)
    assert float(jnp.min(mixed)) >= 0.5 / K**2 - 1e-9
    np.testing.assert_allclose(float(jnp.sum(mixed)), 1.0, rtol=1e-5)
    with pytest.raises(ValueError, match="uniform_mix"):
        LSDSampler(model, params, uniform_mix=1.5)
    del FREE, embed_local_distribution


@pytest.mark.slow
def test_export_and_load_model_file_round_trip(run, tmp_path):
    from jaxsem.lsd import PRETRAINED_CPU, export_model, load_model

    wd, res = run
    _, params, cfg = load_trained(wd)
    path = export_model(tmp_path / "m.npz", cfg, params)
    model, p2, cfg2, _ = load_model(path)
    assert cfg2 == cfg and model.config == MODEL
    for a, b in zip(jax.tree_util.tree_leaves(params), jax.tree_util.tree_leaves(p2)):
        np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="path: no such model file"):
        load_model(tmp_path / "missing.npz")
    if PRETRAINED_CPU.exists():  # the bundled model matches the 160 x 160 planner crops
        m, _, c, _ = load_model()
        assert m.config.map_size == 160 and c.model.context_dim == 4


def test_the_model_file_carries_the_cell_size_it_was_trained_on(tmp_path):
    from jaxsem import lsd

    model, params, cfg, meta = lsd.load_model()
    assert meta["cell_size"] == 0.1  # shipped models: the generator's 0.1 m buildings
    assert LSDSampler(model, params).cell_size == 0.1
    path = lsd.export_model(tmp_path / "fine.npz", cfg, params, cell_size=0.05)
    assert lsd.load_model(path).meta["cell_size"] == 0.05
    with pytest.raises(ValueError, match="cell_size"):
        lsd.export_model(tmp_path / "bad.npz", cfg, params, cell_size=0.0)
    with pytest.raises(ValueError, match="cell_size"):
        LSDSampler(model, params, cell_size=float("nan"))


def test_shipped_model_is_the_default():
    from jaxsem.lsd import PRETRAINED, load_model
    from jaxsem.lsd._train import load_model_file  # layers: white-box

    assert PRETRAINED.exists() and PRETRAINED.with_name("MODEL_CARD.md").exists()
    model, params, cfg, _ = load_model()
    _, _, cfg_file = load_model_file(PRETRAINED)
    assert cfg == cfg_file and cfg.model.log_range == 8.0 and model.config.map_size == 160


def test_the_generated_building_model_loads_by_name_beside_the_default():
    import jax

    from jaxsem import lsd

    _, params, config, meta = lsd.load_model("generated")
    _, default_params, default_config, _ = lsd.load_model("default")
    assert meta["name"].endswith("pretrained_generated.npz")
    assert config.model == default_config.model  # the default is its fine-tune: the same network
    leaves = [np.asarray(x) for x in jax.tree_util.tree_leaves(params)]
    other = [np.asarray(x) for x in jax.tree_util.tree_leaves(default_params)]
    assert all(np.isfinite(x).all() for x in leaves)
    assert any(not np.array_equal(a, b) for a, b in zip(leaves, other))


def test_new_networks_resize_and_old_configs_load_as_transposed(tmp_path):
    """A new LSDConfig upsamples without stripes; a config saved before the field existed (the
    first bundled model's) still describes, and loads, its transposed network."""
    import json

    from jaxsem.lsd import PRETRAINED_CPU, load_model

    assert LSDConfig().upsample == "resize" and TrainConfig().model.upsample == "resize"
    with np.load(PRETRAINED_CPU) as z:
        saved = json.loads(str(z["config_json"]))
    assert "upsample" not in saved["model"]
    model, params, cfg, _ = load_model(PRETRAINED_CPU)
    assert cfg.model.upsample == "transpose" and model.config.upsample == "transpose"
    assert params["dec_0"]["kernel"].shape[:2] == (2, 2)


def test_shipped_model_distribution_has_no_upsampling_stripes():
    """Issue 11 item 5: the distribution images of the model shipped before had a block pattern
    (2 x 2 stride-2 transposed convolutions: one kernel per cell parity). Windows of two
    held-out buildings after a 360-degree look around: the power of the log-distribution at the
    frequencies of periods 16, 8, 4 and 2 cells stays within 2x of the neighbouring frequencies
    (the transposed model: 5.6x at period 4, 8.7x at period 2)."""
    from jaxsem.lsd import load_model
    from jaxsem.planning import empty_map_state, generate_building, local_inputs, sample_tasks, sense

    model, params, _, _ = load_model()
    sampler = LSDSampler(model, params)
    logs = []
    for seed in (701, 702):
        b = generate_building(seed, "test")
        for task in sample_tasks(b, "IO", 2, seed=seed):
            state = empty_map_state(b.shape)
            for yaw in np.linspace(0.0, 2.0 * np.pi, 8, endpoint=False):
                state = sense(b.occupancy, b.semantic, state, np.array([*task.start, yaw]), b)
            inputs = local_inputs(state, task.start, task.goal, task.goal_outdoors, b)
            prob = np.asarray(sampler(inputs), np.float64)
            assert np.all(np.isfinite(prob)) and np.all(prob > 0)
            logs.append(np.log(prob))
    x = np.stack(logs)
    x -= x.mean(axis=(-2, -1), keepdims=True)
    power = np.abs(np.fft.fft2(x)) ** 2
    spectrum = (power.sum(-2) + power.sum(-1)).mean(0)  # along rows and columns, over windows
    k = x.shape[-1]
    for period in (16, 8, 4, 2):
        f = k // period
        neighbours = np.mean([spectrum[f + d] for d in (-3, -2, 2, 3) if 0 < f + d <= k // 2])
        assert spectrum[f] < 2.0 * neighbours, f"period {period}: peak {spectrum[f] / neighbours:.1f}x"


@pytest.mark.slow
def test_cosine_schedule_decays_each_stage_and_resumes_exactly(tmp_path, optax_promotion):  # optax directly
    from jaxsem.lsd._train import stage_optimizer  # layers: white-box

    cfg = dataclasses.replace(CFG, lr_schedule="cosine", stage1_steps=20, stage2_steps=10)
    # Adam's step for a constant gradient is the rate itself: the first step of each stage moves
    # by its learning rate, the last by a little over a tenth of it.
    for stage, n in ((1, 20), (2, 10)):
        tx = stage_optimizer(cfg, stage)
        x = jnp.zeros(())
        state = tx.init(x)
        moves = []
        for _ in range(n):
            upd, state = tx.update(jnp.ones(()), state, x)
            moves.append(-float(upd))
        assert moves[0] == pytest.approx(1e-2, rel=1e-3)
        assert 0.99e-3 < moves[-1] < 1.3e-3
        assert all(a >= b for a, b in zip(moves, moves[1:]))
    # A chunked cosine run (stopped mid-stage and in stage two) equals an uninterrupted one.
    short = dataclasses.replace(cfg, stage1_steps=4, stage2_steps=4)
    whole = train_and_evaluate(short, tmp_path / "a", data=_data(), progress=False)
    train_and_evaluate(short, tmp_path / "b", data=_data(), progress=False, stop_at=3)
    chunked = train_and_evaluate(short, tmp_path / "b", data=_data(), progress=False, stop_at=6)
    chunked = train_and_evaluate(short, tmp_path / "b", data=_data(), progress=False)
    assert chunked.resumed_from == 6
    for a, b in zip(jax.tree_util.tree_leaves(whole.params), jax.tree_util.tree_leaves(chunked.params)):
        np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-7)
    with pytest.raises(ValueError, match="lr_schedule"):
        TrainConfig(lr_schedule="linear")
    with pytest.raises(ValueError, match="stage"):
        stage_optimizer(cfg, 3)


def test_distribution_figure_titles_print_the_context_rounded(tmp_path, axes_titles):
    # regression: float32 context through tolist() printed 0.47999998927..., and the titles of
    # neighbouring panels ran into each other
    k = 16
    batch = {
        "occupancy": np.zeros((2, k, k), np.int8),
        "semantic": np.zeros((2, k, k), np.int8),
        "context": np.array([[0.48, -0.88, 1.0, 0.0], [0.15, 0.76, 0.0, 1.0]], np.float32),
        "path_mask": np.eye(k, dtype=bool)[None].repeat(2, 0),
    }
    path = tmp_path / "dist.png"
    save_distribution_figure(path, batch, np.full((2, k, k), -np.log(k * k)), title="t")
    assert path.stat().st_size > 0
    ctx_titles = [t for t in axes_titles if "ctx" in t]
    assert len(ctx_titles) == 2
    assert "0.48" in ctx_titles[0] and "-0.88" in ctx_titles[0]
    assert all(len(t.split("\n")[-1]) <= 32 for t in ctx_titles), ctx_titles


def test_warm_start_turns_a_transposed_kernel_into_its_parity_average():
    # Reference: flax's own layers. A 2 x 2 stride-2 transposed convolution averaged over each
    # 2 x 2 output block equals the warm-started 3 x 3 convolution on the nearest-doubled input.
    import flax.linen as nn

    from jaxsem.lsd._train import warm_start_params  # layers: white-box

    x = jax.random.normal(jax.random.PRNGKey(1), (2, 5, 7, 3), jnp.float32)  # flax params: float32
    tconv, conv = nn.ConvTranspose(4, (2, 2), strides=(2, 2)), nn.Conv(4, (3, 3))
    pt = tconv.init(jax.random.PRNGKey(2), x)["params"]
    up = jnp.repeat(jnp.repeat(x, 2, axis=1), 2, axis=2)
    pc = conv.init(jax.random.PRNGKey(3), up)["params"]
    warm = warm_start_params({"dec_0": pc}, {"dec_0": pt})["dec_0"]
    yt = tconv.apply({"params": pt}, x)
    block_mean = yt.reshape(2, 5, 2, 7, 2, 4).mean(axis=(2, 4))
    yc = conv.apply({"params": warm}, up)
    np.testing.assert_allclose(yc, jnp.repeat(jnp.repeat(block_mean, 2, axis=1), 2, axis=2), atol=1e-5)
    # the same network: a plain copy
    same = warm_start_params({"dec_0": pt}, {"dec_0": pt})
    np.testing.assert_array_equal(same["dec_0"]["kernel"], pt["kernel"])
    with pytest.raises(ValueError, match="src: has no parameter 'dec_1/"):
        warm_start_params({"dec_1": pt}, {"dec_0": pt}, "src")
    with pytest.raises(ValueError, match="src: parameter 'dec_0/kernel' has shape"):
        warm_start_params({"dec_0": {"kernel": jnp.zeros((3, 3, 3, 5)), "bias": pt["bias"]}}, {"dec_0": pt}, "src")


@pytest.mark.slow
def test_init_from_fine_tunes_a_resize_network_from_an_exported_model(run, tmp_path):
    from jaxsem.lsd import export_model
    from jaxsem.lsd._train import warm_start_params  # layers: white-box

    wd, _ = run
    _, params, cfg = load_trained(wd)
    src = export_model(tmp_path / "src.npz", cfg, params)
    resize = dataclasses.replace(MODEL, upsample="resize")
    still = dataclasses.replace(
        CFG, model=resize, init_from=str(src), learning_rate=0.0, stage1_steps=1, stage2_steps=0
    )
    res = train_and_evaluate(still, tmp_path / "ft", data=_data(), progress=False)
    _, fresh = init_lsd(jax.random.PRNGKey(still.seed), resize)
    expected = warm_start_params(fresh, params)
    for a, b in zip(jax.tree_util.tree_leaves(expected), jax.tree_util.tree_leaves(res.params)):
        np.testing.assert_allclose(a, b, atol=1e-7)
    # a training workdir serves as well as its export
    res_wd = train_and_evaluate(
        dataclasses.replace(still, init_from=str(wd)), tmp_path / "ft3", data=_data(), progress=False
    )
    for a, b in zip(jax.tree_util.tree_leaves(res.params), jax.tree_util.tree_leaves(res_wd.params)):
        np.testing.assert_array_equal(a, b)
    wrong = dataclasses.replace(still, model=dataclasses.replace(MODEL, features=(4, 8, 16)))
    with pytest.raises(ValueError, match="init_from: parameter"):
        train_and_evaluate(wrong, tmp_path / "ft2", data=_data(), progress=False)
    with pytest.raises(ValueError, match="init_from: no such model file or training workdir"):
        train_and_evaluate(
            dataclasses.replace(still, init_from=str(tmp_path / "nope.npz")),
            tmp_path / "ft4",
            data=_data(),
            progress=False,
        )


def test_both_model_loaders_return_one_shape():
    # issue 23: volumon.load_pretrained gave 4 values and lsd.load_model 3; both give a LoadedModel
    from jaxsem import training, volumon
    from jaxsem.lsd import load_model

    lsd_model = load_model()
    vol_model = volumon.load_pretrained()
    for loaded in (lsd_model, vol_model):
        assert isinstance(loaded, training.LoadedModel) and len(loaded) == 4
        assert set(loaded.meta) >= {"name"}
    assert lsd_model.params is lsd_model.variables and lsd_model.meta["step"] is None


def test_two_stage_optimizer_runs_each_stage_as_a_fresh_adam(optax_promotion):  # optax directly
    """Issue 23: one optax transformation for both stages. Reference: the two separate stage
    optimisers, the second one started fresh at the boundary (the loop before the single step)."""
    from jaxsem.lsd import two_stage_optimizer
    from jaxsem.lsd._train import STAGE_LABELS, stage_optimizer  # layers: white-box
    from jaxsem.models import is_context_param

    cfg = dataclasses.replace(CFG, lr_schedule="cosine", weight_decay=1e-3, stage1_steps=2, stage2_steps=2)
    params = {"enc_0": {"kernel": jnp.ones((2, 3)), "bias": jnp.zeros(3)}, "cs_0": {"kernel": jnp.full((4,), 0.5)}}
    assert is_context_param("cs_0") and not is_context_param("enc_0")
    gen, cs = split_params(params)
    grads = [jax.tree.map(lambda x, i=i: jnp.sin(x + i), params) for i in range(cfg.total_steps)]
    tx = two_stage_optimizer(cfg)
    state = tx.init(params)
    ref = {1: stage_optimizer(cfg, 1), 2: stage_optimizer(cfg, 2)}
    ref_state = {1: ref[1].init(gen), 2: None}  # stage two's optimiser starts at the boundary
    ref_params = {1: gen, 2: cs}
    p = params
    for i, g in enumerate(grads):
        stage = 1 if i < cfg.stage1_steps else 2
        if ref_state[stage] is None:
            ref_state[stage] = ref[stage].init(ref_params[stage])
        upd, state = jax.jit(tx.update)(g, state, p)
        ref_upd, ref_state[stage] = jax.jit(ref[stage].update)(
            split_params(g)[stage - 1], ref_state[stage], ref_params[stage]
        )
        ref_params[stage] = optax.apply_updates(ref_params[stage], ref_upd)
        p = optax.apply_updates(p, upd)
        active, frozen = split_params(upd)[stage - 1], split_params(upd)[2 - stage]
        for a, b in zip(jax.tree.leaves(active), jax.tree.leaves(ref_upd)):
            np.testing.assert_allclose(a, b, rtol=1e-12, atol=0)
        assert all(not np.any(np.asarray(u)) for u in jax.tree.leaves(frozen))
        # the inactive optimiser's state (moments, Adam's and the schedule's counts) stays put
        idle = state.inner_states[STAGE_LABELS[3 - stage]].inner_state.inner_state
        fresh = tx.init(params).inner_states[STAGE_LABELS[3 - stage]].inner_state.inner_state
        if stage == 1:
            for a, b in zip(jax.tree.leaves(idle), jax.tree.leaves(fresh)):
                np.testing.assert_array_equal(a, b)
        assert int(state.inner_states[STAGE_LABELS[1]].inner_state.step) == i + 1
    for a, b in zip(jax.tree.leaves(split_params(p)), jax.tree.leaves((ref_params[1], ref_params[2]))):
        np.testing.assert_allclose(a, b, rtol=1e-12)


def _reference_two_step_run(cfg, data, snapshot_at: int):
    """The schedule before the single step, written out: stage one's own jitted step and
    optimiser, then a fresh optimiser and stage two's step at the boundary. Returns the final
    params, the losses and a legacy-layout checkpoint state (params, the current stage's
    optimiser state, step) at step ``snapshot_at``."""
    from jaxsem.lsd import make_train_step
    from jaxsem.lsd._data import batch_indices, gather_batch  # layers: white-box
    from jaxsem.lsd._train import stage_optimizer  # layers: white-box

    model, params = init_lsd(jax.random.PRNGKey(cfg.seed), cfg.model, jnp.float32)
    params = jax.tree.map(jnp.copy, params)
    train_idx, _ = split_by_building(data, cfg.val_fraction, cfg.seed, cfg.val_every_nth_building)
    drop_key = jax.random.key(cfg.seed, impl="rbg")
    opt_state, losses, snapshot = None, [], None
    for step in range(cfg.total_steps):
        if step == snapshot_at:
            copy = functools.partial(jax.tree.map, np.array)  # the step donates its state
            snapshot = {"params": copy(params), "opt_state": copy(opt_state), "step": np.asarray(step, np.int64)}
        stage = 1 if step < cfg.stage1_steps else 2
        tx = stage_optimizer(cfg, stage)
        if step in (0, cfg.stage1_steps):
            opt_state = tx.init(split_params(params)[stage - 1])
        batch = gather_batch(data, batch_indices(train_idx, cfg.batch_size, step, cfg.seed))
        with jax.numpy_dtype_promotion("standard"):  # optax's adam inside
            params, opt_state, loss = make_train_step(model, tx, stage)(
                params, opt_state, batch, jax.random.fold_in(drop_key, step)
            )
        losses.append(float(loss))
    return params, losses, snapshot


def _assert_same_training(params, ref):
    """Equal up to float32 round-off, except the biases of the two output layers: the softmax
    over the window does not change when a constant is added to all logits (unbounded output,
    ``log_range`` None), so their gradient is round-off, which Adam scales up to a step of the
    learning rate's size and random sign (they differ by up to 0.005 between two compiled
    programs of the same arithmetic)."""
    shift_invariant = {"dec_out", "cs_out"}
    assert MODEL.log_range is None
    for layer in params:
        for name in params[layer]:
            if name == "bias" and layer in shift_invariant:
                continue
            np.testing.assert_allclose(params[layer][name], ref[layer][name], rtol=1e-5, atol=1e-6, err_msg=layer)


@pytest.mark.slow
def test_one_compiled_step_equals_the_two_stage_schedule_and_resumes_exactly(tmp_path):
    """Issue 23: both stages in one compiled step give the old schedule's parameters and losses;
    a run stopped before the stage boundary resumes bit-identically across it; a checkpoint in
    the old layout (one stage's optimiser state) loads and resumes as the old loop continued."""
    import json
    import shutil

    from jaxsem.checkpoint import Checkpointer

    cfg = dataclasses.replace(CFG, lr_schedule="cosine", stage1_steps=3, stage2_steps=3, checkpoint_every=100)
    data = _data()
    whole = train_and_evaluate(cfg, tmp_path / "whole", data=data, progress=False)
    ref_params, ref_losses, legacy = _reference_two_step_run(cfg, data, snapshot_at=4)
    _assert_same_training(whole.params, ref_params)
    # train_nll of an evaluation: the mean of that stage's losses
    nll = [h["train_nll"] for h in whole.history]
    np.testing.assert_allclose(nll, [np.mean(ref_losses[:3]), np.mean(ref_losses[3:])], rtol=1e-5)
    _, gen_end, _ = load_trained(tmp_path / "whole", step=cfg.stage1_steps)  # the stage-one checkpoint
    assert split_params(gen_end)[1] and all(
        np.array_equal(a, b)
        for a, b in zip(jax.tree.leaves(split_params(gen_end)[0]), jax.tree.leaves(split_params(whole.params)[0]))
    )

    # stopped at step 2 (stage one), resumed: across the boundary, bit-identical
    train_and_evaluate(cfg, tmp_path / "chunked", data=data, progress=False, stop_at=2)
    chunked = train_and_evaluate(cfg, tmp_path / "chunked", data=data, progress=False)
    assert chunked.resumed_from == 2
    for a, b in zip(jax.tree.leaves(whole.params), jax.tree.leaves(chunked.params)):
        np.testing.assert_array_equal(a, b)

    # a legacy checkpoint (step 4, stage two's optimiser state only) resumes as the old loop
    wd = tmp_path / "legacy"
    train_and_evaluate(cfg, wd, data=data, progress=False, stop_at=4)
    shutil.rmtree(wd / "checkpoints")
    with Checkpointer(wd / "checkpoints") as ckpt:
        ckpt.save(4, legacy)
    _, loaded, _ = load_trained(wd)
    for a, b in zip(jax.tree.leaves(loaded), jax.tree.leaves(legacy["params"])):
        np.testing.assert_array_equal(a, b)
    resumed = train_and_evaluate(cfg, wd, data=data, progress=False)
    assert resumed.resumed_from == 4 and json.loads((wd / "config.json").read_text())["stage1_steps"] == 3
    _assert_same_training(resumed.params, ref_params)
