"""An ``.npz`` whose headers declare more than the budget is refused before anything inflates:
a model file or a data shard of a few hundred bytes can declare gigabytes."""

import io
import time
import tracemalloc
import zipfile

import numpy as np
import pytest

from jaxsem._files import check_npz  # layers: white-box


def _declaring(path, shape, dtype="<f8"):
    """An .npz of one array whose header declares ``shape`` but holds a few bytes of data."""
    head = io.BytesIO()
    np.lib.format.write_array_header_1_0(head, {"descr": dtype, "fortran_order": False, "shape": shape})
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("weights.npy", head.getvalue() + b"\0" * 64)
    return path


def test_declared_size_over_budget_is_refused_by_name(tmp_path):
    big = _declaring(tmp_path / "model.npz", (60000, 60000))
    tracemalloc.start()
    t0 = time.perf_counter()
    with pytest.raises(ValueError, match=r"model.npz: declares 3,600,000,000 array elements .*'weights'.*max_elements"):
        check_npz(big)
    assert time.perf_counter() - t0 < 1.0
    assert tracemalloc.get_traced_memory()[1] < 50 * 2**20
    tracemalloc.stop()
    small = tmp_path / "ok.npz"
    np.savez(small, a=np.zeros((3, 4)), b=np.ones(5))
    assert check_npz(small) == {"a": (3, 4), "b": (5,)}
    with pytest.raises(ValueError, match="max_elements=16"):
        check_npz(small, max_elements=16)


def test_an_lsd_model_file_is_checked_before_it_loads(tmp_path):
    from jaxsem.lsd._train import load_model_file  # layers: white-box

    with pytest.raises(ValueError, match="more than max_elements"):
        load_model_file(_declaring(tmp_path / "lsd.npz", (2**16, 2**16)))
