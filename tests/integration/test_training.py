"""The shared training scaffold (jaxsem.training): resume, config check, metrics, and that VoluMon
and LSD both train through it (one contract: same error, same workdir layout)."""

import dataclasses
import json

import numpy as np
import pytest

from jaxsem import (
    lsd,
    training as lsd_training,  # layers: white-box
    training as volumon_training,  # layers: white-box
    volumon,
)
from jaxsem.training import (
    ConfigMismatchError,
    TrainingRun,
    config_json,
    read_exported,
    read_metrics,
    read_run_config,
)
from jaxsem.volumon._configs import PRESETS  # layers: white-box


@dataclasses.dataclass(frozen=True)
class _Inner:
    width: int = 4
    sizes: tuple = (1, 2)


@dataclasses.dataclass(frozen=True)
class _Cfg:
    inner: _Inner = _Inner()
    lr: float = 0.1
    steps: int = 10


def _toy_run(workdir, cfg, end, *, stop=None, force=False, lines=None):
    """A toy 'training' (state = running sum of the step numbers) through the scaffold."""
    state = {"x": np.zeros(3), "step": np.zeros((), np.int64)}
    with TrainingRun(
        workdir,
        config_json(cfg),
        keep=2,
        resumable=("steps",),
        force=force,
        log=None if lines is None else lines.append,
    ) as run:
        if run.latest_step is not None:
            state = run.restore(state)
        run.begin()
        last = end if stop is None else stop
        for step in run.steps(run.start, last, total=end, desc="toy", progress=False):
            state = {"x": state["x"] + step, "step": np.asarray(step + 1, np.int64)}
            run.log_metrics({"step": step + 1, "x0": float(state["x"][0])})
            if (step + 1) % 3 == 0 or step + 1 == last:
                run.save(step + 1, state)
    return state


def test_resume_equals_uninterrupted_and_keeps_one_row_per_step(tmp_path):
    cfg = _Cfg()
    whole = _toy_run(tmp_path / "a", cfg, 10)
    # Interrupted after step 5: the checkpoint is at 3 (every 3), rows 4 and 5 were written after it.
    _toy_run(tmp_path / "b", cfg, 10, stop=5)
    ckpt_rows = read_metrics(tmp_path / "b")
    assert [r["step"] for r in ckpt_rows] == [1, 2, 3, 4, 5]
    # Simulate a crash between the row and the checkpoint of step 5: keep only the checkpoint of 3.
    import shutil

    shutil.rmtree(tmp_path / "b" / "checkpoints" / "5")
    lines = []
    resumed = _toy_run(tmp_path / "b", dataclasses.replace(cfg, steps=20), 10, lines=lines)
    assert lines == ["resumed from step 3"]
    np.testing.assert_array_equal(resumed["x"], whole["x"])
    steps = [r["step"] for r in read_metrics(tmp_path / "b")]
    assert steps == list(range(1, 11))  # no duplicate rows for steps 4, 5


def test_changed_config_is_refused_naming_the_nested_field(tmp_path):
    _toy_run(tmp_path, _Cfg(), 3)
    changed = _Cfg(inner=_Inner(width=8))
    with pytest.raises(ConfigMismatchError, match=r"inner\.width: checkpoint 4, now 8"):
        _toy_run(tmp_path, changed, 6)
    # force resumes with the new config, which is written.
    _toy_run(tmp_path, changed, 6, force=True)
    assert json.loads((tmp_path / "config.json").read_text())["inner"]["width"] == 8
    assert [r["step"] for r in read_metrics(tmp_path)] == list(range(1, 7))


def test_fresh_run_drops_stale_metrics_and_bad_rows_need_a_step(tmp_path):
    (tmp_path / "metrics.jsonl").write_text('{"step": 7, "x0": 1}\nnot json\n')
    with TrainingRun(tmp_path, config_json(_Cfg())) as run:
        run.begin()
        assert run.metrics() == []
        with pytest.raises(ValueError, match="row: expected a 'step' key"):
            run.log_metrics({"x0": 1.0})
    with pytest.raises(ValueError, match="config: expected a dataclass or a mapping"):
        config_json(3)


def test_unreadable_config_json_is_refused_clearly(tmp_path):
    _toy_run(tmp_path, _Cfg(), 3)
    (tmp_path / "config.json").write_text("{broken")
    with pytest.raises(ConfigMismatchError, match="cannot read the run's config"):
        _toy_run(tmp_path, _Cfg(), 6)


@pytest.mark.parametrize(
    ("content", "words"),
    [
        (b'{"seed": }', ["not JSON", "line 1"]),
        (b'{"seed": "\xe9"}', ["not UTF-8"]),
        (b"[1, 2]", ["expected a JSON object"]),
    ],
    ids=["json", "latin", "list"],
)
def test_a_corrupt_config_json_is_named_by_every_reader(tmp_path, content, words):
    # Issue 45 item 7: a corrupt config.json gave the bare "Expecting value: line 1 column 11".
    (tmp_path / "config.json").write_bytes(content)
    readers = [read_run_config, lsd.load_trained, volumon.load_trained, volumon.load_pretrained]
    readers += [lambda w: volumon.export_pretrained(w, out_dir=tmp_path / "shipped"), lambda w: _toy_run(w, _Cfg(), 1)]
    _toy_run(tmp_path / "fresh", _Cfg(), 1)  # checkpoints, so the resume reads the config
    (tmp_path / "fresh" / "config.json").write_bytes(content)
    for reader, workdir in zip(readers, [tmp_path] * 5 + [tmp_path / "fresh"]):
        with pytest.raises(ValueError) as info:
            reader(workdir)
        assert str(workdir / "config.json") in str(info.value), str(info.value)
        for word in words:
            assert word in str(info.value), str(info.value)


def test_volumon_and_lsd_share_the_contract():
    # One error type for a mismatched resume, one load_trained signature (workdir, config=None, *, step=None).
    assert volumon_training.ConfigMismatchError is lsd_training.ConfigMismatchError is ConfigMismatchError
    import inspect

    for fn in (volumon.load_trained, lsd.load_trained):
        params = inspect.signature(fn).parameters
        assert list(params)[:2] == ["workdir", "config"]
        assert params["step"].kind is inspect.Parameter.KEYWORD_ONLY


def test_both_models_take_named_presets_or_a_json_file(tmp_path):
    # One way to configure: a preset by name, or a JSON file of fields over the default.
    assert {"default", "cpu", "scale", "tiny"} <= set(lsd.PRESETS.names)
    assert {"default", "cpu", "fast", "thesis", "tiny"} <= set(PRESETS.names)
    assert lsd.get_config("tiny").stage1_steps < lsd.get_config("default").stage1_steps
    f = tmp_path / "lsd.json"
    f.write_text(json.dumps({"batch_size": 3, "model": {"log_range": 6.0}}))
    got = lsd.get_config(str(f))
    assert got.batch_size == 3 and got.model.log_range == 6.0
    assert got.stage1_steps == lsd.get_config("default").stage1_steps
    g = tmp_path / "vm.json"
    g.write_text(json.dumps({"num_steps": 7, "loss": {"pixel_scale": 2.0}}))
    vm = volumon.get_config("dual", str(g))
    assert vm.num_steps == 7 and vm.loss.pixel_scale == 2.0 and vm.loss.alpha_P == 0.0
    with pytest.raises(ValueError, match="config .nope.: unknown preset"):
        lsd.get_config("nope")
    with pytest.raises(ValueError, match="size: expected one of"):
        volumon.get_config("both", "nope")
    h = tmp_path / "bad.json"
    h.write_text(json.dumps({"no_such_field": 1}))
    with pytest.raises(ValueError, match="no_such_field"):
        lsd.get_config(str(h))


def test_train_commands_take_a_config_file_and_name_a_missing_one(tmp_path, capsys):
    from jaxsem.cli import main

    with pytest.raises(SystemExit) as exc:
        main(["volumon", "train", "--workdir", str(tmp_path / "w"), "--size", str(tmp_path / "none.json")])
    assert exc.value.code != 0
    assert "--size" in capsys.readouterr().err
    assert not (tmp_path / "w").exists()


def test_stamp_guards_a_resumable_folder(tmp_path):
    from jaxsem.training import ConfigMismatchError, check_stamp

    out = tmp_path / "chunks"
    check_stamp(out / "stamp.json", {"seed": 1, "config": {"size": [320, 240]}})  # written
    check_stamp(out / "stamp.json", {"seed": 1, "config": {"size": (320, 240)}})  # the same (tuple = list)
    with pytest.raises(ConfigMismatchError, match=r"config.size: made with \[320, 240\], now \[256, 192\]"):
        check_stamp(out / "stamp.json", {"seed": 1, "config": {"size": [256, 192]}}, hint="another folder")
    # A folder holding output without a stamp is refused, unless adopted.
    old = tmp_path / "old"
    old.mkdir()
    (old / "chunk_0000.npz").write_bytes(b"x")
    with pytest.raises(ConfigMismatchError, match="no record of the settings"):
        check_stamp(old / "stamp.json", {"seed": 1})
    check_stamp(old / "stamp.json", {"seed": 1}, adopt=True)
    assert (old / "stamp.json").is_file()
    (old / "stamp.json").write_text("{not json")
    with pytest.raises(ConfigMismatchError, match="stamp.json: not a readable record"):
        check_stamp(old / "stamp.json", {"seed": 1})
    (old / "stamp.json").write_bytes(b'{"seed": "\xff"}')  # not UTF-8: named, not the codec's words
    with pytest.raises(
        ConfigMismatchError, match=r"stamp\.json: not a readable record of settings \(not UTF-8 text: byte 10\)"
    ):
        check_stamp(old / "stamp.json", {"seed": 1})


def test_an_exported_model_reads_back_as_its_tree_config_and_meta(tmp_path):
    path = tmp_path / "model.npz"
    np.savez(path, **{"params/dense/kernel": np.ones((2, 3), np.float32), "batch_stats/mean": np.zeros(3, np.float32)})
    path.with_suffix(".json").write_text(json.dumps({"name": "m", "config": {"lr": 0.5}}))
    config, variables, meta = read_exported(path, lambda d: _Cfg(**d))
    assert config == _Cfg(lr=0.5) and meta["name"] == "m"
    assert variables["params"]["dense"]["kernel"].shape == (2, 3) and variables["batch_stats"]["mean"].shape == (3,)
    path.with_suffix(".json").write_text(json.dumps(["not", "an", "object"]))
    with pytest.raises(ValueError, match="model.json: expected a JSON object with the model's 'config'"):
        read_exported(path, lambda d: _Cfg(**d))
