"""The package's layers, checked on the import statements of every file (an import-linter contract).

- geometry (``quadrics`` with its private implementation package ``_geometry``, ``classes``,
  ``_checks``) imports nothing else of jaxsem (``quadrics`` and ``_geometry`` are one unit);
- shared data (``data``: the BOP and FAT readers and writer, the renderer, the fetcher) imports
  geometry only: it is what every method shares, and knows none of them;
- methods (``metrics``, ``factors``, ``slam``, ``models``, ``volumon``, ``lsd``, ``planning``,
  ``mapping``, ``parallel``) import geometry, shared data and each other, never the outer layer;
- the outer layer (the deprecated ``sim`` alias, ``demos``, ``cli``, ``_commands``, scripts, tests,
  benchmarks) may import anything public;
- nobody imports ``jaxsem.x._private`` from outside package ``x`` (a test or benchmark may, on an import
  line marked ``# layers: white-box``).
"""

import ast
import functools
import pathlib

ROOT = pathlib.Path(__file__).resolve().parents[1]
GEOMETRY = {"quadrics", "_geometry", "classes", "_checks"}
# The geometry core: the public facade and the private package behind it, one unit of the layer.
GEOMETRY_CORE = {"quadrics", "_geometry"}
METHODS = {
    "metrics",
    "factors",
    "slam",
    "models",
    "volumon",
    "lsd",
    "planning",
    "mapping",
    "parallel",
    "checkpoint",
    "training",
}
SHARED_DATA = {"data"}
OUTER = {"sim", "demos", "cli", "_commands"}


@functools.cache
def _imports(path: pathlib.Path) -> tuple:
    """(line, absolute dotted jaxsem module name) imported by ``path`` (relative imports
    resolved); parsed once per session, as every test here reads every file."""
    return tuple(_parse_imports(path))


def _parse_imports(path: pathlib.Path):
    rel = path.relative_to(ROOT)
    package = list(rel.parts[:-1]) if rel.parts[0] == "jaxsem" else []
    if rel.name == "__init__.py":
        package = list(rel.parts[:-1])
    text = path.read_text()
    lines = text.splitlines()
    tree = ast.parse(text, str(path))
    for node in ast.walk(tree):
        # A test or a benchmark may look inside a package when its import line says why ("# layers: white-box").
        lineno = getattr(node, "lineno", None)
        if rel.parts[0] in ("tests", "benchmarks") and lineno and "# layers: white-box" in lines[lineno - 1]:
            continue
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            if mod.startswith("jaxsem"):
                yield node.lineno, mod
                for alias in node.names:
                    yield node.lineno, f"{mod}.{alias.name}"
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.startswith("jaxsem"):
                    yield node.lineno, alias.name


def _files():
    for folder in ("jaxsem", "tests", "benchmarks", "train", "infer", "examples"):
        yield from sorted((ROOT / folder).rglob("*.py"))


def _owner(path: pathlib.Path) -> str:
    rel = path.relative_to(ROOT)
    if rel.parts[0] != "jaxsem":
        return "<outside>"
    return rel.parts[1].removesuffix(".py") if len(rel.parts) > 1 else ""


def test_no_private_imports_across_packages():
    bad = []
    for path in _files():
        owner = _owner(path)
        for line, mod in _imports(path):
            parts = mod.split(".")
            for i, part in enumerate(parts[1:], start=1):
                if part.startswith("_") and not part.startswith("__"):
                    # jaxsem.x._y is private to package x; jaxsem._y (top level) to the jaxsem package.
                    allowed = (i == 1 and owner != "<outside>") or (i >= 2 and parts[1] == owner)
                    if not allowed:
                        bad.append(f"{path.relative_to(ROOT)}:{line} imports {mod}")
                    break
    assert not bad, "private imports across packages:\n" + "\n".join(sorted(set(bad)))


def test_layers_point_one_way():
    bad = []
    for path in _files():
        owner = _owner(path)
        if owner in GEOMETRY:
            same_unit = GEOMETRY_CORE if owner in GEOMETRY_CORE else {owner}
            forbidden = METHODS | OUTER | SHARED_DATA | (GEOMETRY - same_unit - {"_checks"})
        elif owner in SHARED_DATA:
            forbidden = METHODS | OUTER
        elif owner in METHODS:
            forbidden = OUTER
        else:
            continue
        for line, mod in _imports(path):
            parts = mod.split(".")
            if len(parts) > 1 and parts[1] in forbidden:
                bad.append(f"{path.relative_to(ROOT)}:{line} ({owner}) imports {mod}")
    assert not bad, "imports against the layers:\n" + "\n".join(sorted(set(bad)))


def test_geometry_package_only_behind_its_facade():
    # jaxsem._geometry is the implementation of jaxsem.quadrics: everyone else imports the facade.
    bad = []
    for path in _files():
        if _owner(path) in GEOMETRY_CORE:
            continue
        for line, mod in _imports(path):
            if mod == "jaxsem._geometry" or mod.startswith("jaxsem._geometry."):
                bad.append(f"{path.relative_to(ROOT)}:{line} imports {mod}")
    assert not bad, "import jaxsem.quadrics instead of its private package:\n" + "\n".join(sorted(set(bad)))
