"""What ships names no path of the machine it was made on: the package's files (code, model
metadata, model cards) and the string constants of the benchmark, training and example scripts
(their defaults). A user's machine has none of those folders."""

import ast
import pathlib
import re

ROOT = pathlib.Path(__file__).resolve().parents[2]
MACHINE = re.compile(r"(?<![\w.~$])/(?:work|root|home|check|mnt|Users)/[\w.-]+|/tmp/(?:realdata|gq)\b")
TEXT = {".py", ".json", ".md", ".txt", ".yaml", ".yml", ".toml", ".cfg"}


def _package_hits():
    for path in sorted((ROOT / "jaxsem").rglob("*")):
        if path.suffix in TEXT and path.is_file() and "__pycache__" not in path.parts:
            for i, line in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
                if MACHINE.search(line):
                    yield f"{path.relative_to(ROOT)}:{i}: {line.strip()[:100]}"


def _script_hits():
    for folder in ("benchmarks", "train", "examples"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            tree = ast.parse(path.read_text(encoding="utf-8"))
            docs = {
                id(n.body[0].value)
                for n in ast.walk(tree)
                if isinstance(n, (ast.Module, ast.FunctionDef, ast.ClassDef, ast.AsyncFunctionDef))
                and n.body
                and isinstance(n.body[0], ast.Expr)
                and isinstance(n.body[0].value, ast.Constant)
            }
            for node in ast.walk(tree):
                if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docs:
                    if MACHINE.search(node.value):
                        yield f"{path.relative_to(ROOT)}:{node.lineno}: {node.value[:100]!r}"


def test_the_package_names_no_machine_path():
    assert list(_package_hits()) == []


def test_script_defaults_name_no_machine_path():
    assert list(_script_hits()) == []


def test_the_scan_finds_a_planted_path(tmp_path):
    # The pattern catches what it exists for, and leaves relative and placeholder paths alone.
    assert MACHINE.search('"data_dir": "/work/main/runs/doors/data/train"')
    assert MACHINE.search("default=/tmp/gq/bin/python")
    assert not MACHINE.search('"data_dir": "data/train"') and not MACHINE.search("~/data/x")
