import pathlib

import pytest

from jaxsem import cli


@pytest.mark.slow
def test_demo_geometry_writes_figure(tmp_path: pathlib.Path, capsys):
    assert cli.main(["demo", "--parts", "geometry", "--quick", "--out", str(tmp_path)]) == 0
    png = tmp_path / "geometry_boxes.png"
    assert png.exists() and png.stat().st_size > 10_000
    out = capsys.readouterr().out
    assert "| 0 |" in out and "True" in out


def test_demo_rejects_unknown_part(tmp_path, capsys):
    assert cli.main(["demo", "--parts", "nope", "--out", str(tmp_path)]) == 2  # bad input
    assert "unknown part" in capsys.readouterr().err
