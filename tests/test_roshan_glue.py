"""The ROSHAN glue: the demo part, the sequence-directory layout of infer/roshan.py, bad input."""

import pathlib
import re

import numpy as np
import pytest


def _table_rows(table: str) -> dict:
    rows = {}
    for line in table.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) >= 4 and cells[0] in ("baseline", "roshan"):
            rows[cells[0]] = [float(c) for c in cells[1:4]]
    return rows


def test_quick_demo_writes_figure_and_table(tmp_path: pathlib.Path):
    from jaxsem.demos import roshan

    table = roshan.run(tmp_path, quick=True)
    png = tmp_path / "roshan_forward.png"
    assert png.exists() and png.stat().st_size > 10_000
    rows = _table_rows(table)
    assert set(rows) == {"baseline", "roshan"}
    assert all(np.isfinite(v).all() for v in rows.values())
    # Forward flight, fixed seed: ROSHAN's texture planes and shape prior fix the depth the
    # boxes alone leave open (true on every seed tried in float32 and float64).
    assert rows["roshan"][1] < rows["baseline"][1]
    assert re.search(r"\| shape \(m\) \| position \(m\) \| orientation \(deg\)", table)
