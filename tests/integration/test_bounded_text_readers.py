"""Every reader of a user's text file refuses a huge one by its size, before reading a byte, and
names the file; a file that is not UTF-8 gets one line naming it too."""

from __future__ import annotations

import dataclasses
import pathlib

import pytest

import jaxsem.planning._semantics as _semantics  # layers: white-box
from jaxsem import config as cfg, planning, slam
from jaxsem._commands.volumon_predict import read_boxes  # layers: white-box
from jaxsem._files import MAX_JSON_BYTES, MAX_TEXT_BYTES  # layers: white-box
from jaxsem.scripting import UsageError
from jaxsem.volumon import rcnn


@dataclasses.dataclass(frozen=True)
class _Cfg:
    steps: int = 3


def _sparse(path: pathlib.Path, size: int) -> pathlib.Path:
    """A file of ``size`` bytes that takes no disk (a hole): reading it would allocate ``size``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as f:
        f.truncate(size)
    return path


def _not_utf8(path: pathlib.Path) -> pathlib.Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b'{"a": "\xff\xfe"}')
    return path


READERS = {
    "sequence": (lambda p: slam.load_sequence(p), "sequence.json"),
    "map_yaml": (lambda p: planning.load_map(p), "map.yaml"),
    "annotations": (lambda p: _semantics.read_annotations(p), "objects.json"),
    "config": (lambda p: cfg.load(_Cfg, p), "config.json"),
    "boxes": (lambda p: read_boxes(p, (640, 480)), "boxes.json"),
    "rcnn_workdir": (lambda p: rcnn.load_rcnn(p.parent), "config.json"),
}


@pytest.mark.parametrize("name", sorted(READERS))
def test_a_huge_file_is_refused_by_its_size(tmp_path, name):
    read, fname = READERS[name]
    path = _sparse(tmp_path / name / fname, max(MAX_JSON_BYTES, MAX_TEXT_BYTES) + 1)
    with pytest.raises((ValueError, UsageError), match="bytes, more than the max_bytes") as info:
        read(path)
    assert str(path) in str(info.value)


@pytest.mark.parametrize("name", sorted(READERS))
def test_a_file_that_is_not_text_names_the_file(tmp_path, name):
    read, fname = READERS[name]
    path = _not_utf8(tmp_path / name / fname)
    with pytest.raises((ValueError, UsageError)) as info:
        read(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)
