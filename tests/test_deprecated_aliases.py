"""The old import paths of moved code resolve for one release, each with a DeprecationWarning
that names the new home; the project itself never uses them."""

import pathlib
import re

import pytest


@pytest.mark.parametrize(
    "old, name, new",
    [
        ("jaxsem.sim", "simulate", "jaxsem.slam.sim"),
        ("jaxsem.sim", "BuildingRenderer", "jaxsem.mapping"),
        ("jaxsem.sim", "SceneRenderer", "jaxsem.data"),
        ("jaxsem.data", "write_synthetic_dataset", "jaxsem.volumon.data"),
        ("jaxsem.data", "find_stretches", "jaxsem.slam"),
        ("jaxsem.data", "write_door_dataset", "jaxsem.mapping"),
    ],
)
def test_old_name_warns_and_is_the_new_object(old, name, new):
    import importlib

    old_mod, new_mod = importlib.import_module(old), importlib.import_module(new)
    with pytest.warns(DeprecationWarning, match=re.escape(f"{new}.{name}")):
        got = getattr(old_mod, name)
    assert got is getattr(new_mod, name)


def test_unknown_names_are_refused():
    from jaxsem import data, sim

    with pytest.raises(AttributeError, match="no_such_name"):
        sim.no_such_name
    with pytest.raises(AttributeError, match="no_such_name"):
        data.no_such_name


def test_the_project_never_imports_the_old_paths():
    root = pathlib.Path(__file__).resolve().parents[1]
    old = re.compile(
        r"from jaxsem import (.*\b)?sim\b|from jaxsem\.sim\b|import jaxsem\.sim\b|from \.+ import (.*\b)?sim\b"
    )
    offenders = []
    for folder in ("jaxsem", "benchmarks", "examples", "tests"):
        for path in (root / folder).rglob("*.py"):
            if path.parts[-2:] == ("sim", "__init__.py") and path.parent.parent.name == "jaxsem":
                continue
            if path.name == "test_deprecated_aliases.py":
                continue
            if old.search(path.read_text()):
                offenders.append(str(path.relative_to(root)))
    assert offenders == []


def test_load_image_left_the_slam_face_for_the_sequence_method(tmp_path):
    import cv2
    import numpy as np

    from jaxsem import slam
    from jaxsem.slam._sequence_types import Sequence, SequenceFrame  # layers: white-box

    rgb = np.zeros((6, 8, 3), np.uint8)
    rgb[..., 0] = 200  # red, so a channel order mix-up shows
    cv2.imwrite(str(tmp_path / "f.png"), rgb[..., ::-1])
    frame = SequenceFrame(np.eye(4), np.zeros((0, 4)), (), (), np.zeros(0), image="f.png")
    seq = Sequence(np.eye(3), (8, 6), (frame,), root=tmp_path)
    assert "load_image" not in dir(slam)
    with pytest.warns(DeprecationWarning, match=re.escape("sequence.image(t)")):
        old = slam.load_image
    np.testing.assert_array_equal(old(seq, 0), seq.image(0))
    np.testing.assert_array_equal(seq.image(0), rgb)
    with pytest.raises(AttributeError, match="no_such_name"):
        slam.no_such_name
