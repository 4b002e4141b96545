"""benchmarks/lsd/lsd_house_nll.py refuses bad model flags before any expert sample is drawn."""

import pytest


@pytest.mark.parametrize(
    "extra, words",
    [
        (["--extra", "mixed"], "--extra: expected NAME=MODEL with a new name, got 'mixed'"),
        (["--extra", "house=x.npz"], "--extra: expected NAME=MODEL with a new name, got 'house=x.npz'"),
        (["--extra", "oracle=x.npz"], "--extra: expected NAME=MODEL with a new name, got 'oracle=x.npz'"),
        (["--family", "house", "campus", "--model", "x.npz"], "--model: one --family only"),
    ],
    ids=["no-model", "family-name", "oracle-name", "model-two-families"],
)
def test_bad_model_flags_exit_2(extra, words, tmp_path, capsys, script):
    mod = script("benchmarks/lsd/lsd_house_nll.py")
    with pytest.raises(SystemExit) as exc:
        mod.main(["--json", str(tmp_path / "o.json"), *extra])
    assert exc.value.code == 2
    assert words in capsys.readouterr().err.splitlines()[-1]
    assert not (tmp_path / "o.json").exists()
