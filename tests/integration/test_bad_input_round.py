"""benchmarks/integration/bad_input_round.py, on a few of its cases: it writes its inputs, runs each
case as a subprocess and writes the table with its totals."""

import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]


@pytest.mark.slow
def test_the_round_writes_its_table(tmp_path, script):
    mod = script("benchmarks/integration/bad_input_round.py")
    ids = [c.id for c in mod.cases()]
    assert len(ids) == len(set(ids)) >= 90  # every case once
    out = tmp_path / "round.md"
    assert mod.main(["--only", "jaxsem-no-command,map-huge-pgm", "--out", str(out), "--timeout", "120"]) == 0
    text = out.read_text()
    assert "cases: 2 | ok: 2 | tracebacks: 0 | silent acceptances: 0" in text
    rows = [line for line in text.splitlines() if line.startswith("| jaxsem-") or line.startswith("| map-")]
    assert len(rows) == 2 and all(row.rstrip().endswith("| ok |") for row in rows), rows
    assert "huge.pgm: declares 60000 x 60000" in text and str(tmp_path) not in text
