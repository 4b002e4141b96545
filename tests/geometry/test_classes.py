"""One class table: every part of jaxsem that knows an object's size reads jaxsem.classes."""

import numpy as np
import pytest

from jaxsem import classes, factors
from jaxsem.slam import sim


def test_table_rows_are_consistent():
    assert len(set(classes.CLASS_NAMES)) == len(classes.CLASSES)
    car = classes.get("car")
    np.testing.assert_allclose(car.dimensions, [4.88, 1.84, 1.45])
    np.testing.assert_allclose(np.array(car.radii) * 2, car.dimensions)
    assert (
        classes.get("soup_can").shape == "cylinder"
        and classes.get("soup_can").dimensions[2] > classes.get("soup_can").dimensions[0]
    )
    with pytest.raises(ValueError, match="known classes"):
        classes.get("truck")
    with pytest.raises(ValueError, match="dimensions"):
        classes.ObjectClass("bad", "cuboid", (0.1, -0.2, 0.3), (0.01, 0.01, 0.01))
    with pytest.raises(ValueError, match="shape"):
        classes.ObjectClass("bad", "box", (0.1, 0.2, 0.3), (0.01, 0.01, 0.01))


def test_roshan_shape_prior_reads_the_table():
    assert factors.CLASS_NAMES == classes.CLASS_NAMES
    for c in classes.CLASSES:
        prior = factors.shape_prior(c.name)
        np.testing.assert_allclose(2 * np.array(prior.mean), c.dimensions)
        np.testing.assert_allclose(2 * np.array(prior.sigma), c.sigma)


def test_simulator_reads_the_table():
    names = ("car", "chair", "ball")
    mean, sigma = sim.class_table(names)
    for i, name in enumerate(names):
        np.testing.assert_allclose(2 * mean[i], classes.get(name).dimensions)
        np.testing.assert_allclose(2 * sigma[i], classes.get(name).sigma)


def test_synthetic_dataset_classes_read_the_table():
    from jaxsem.volumon.data._synthetic import DEFAULT_CLASSES  # layers: white-box

    for c in DEFAULT_CLASSES:
        ref = classes.get(c.name)
        np.testing.assert_allclose(c.extents, ref.dimensions)
        assert c.shape == {"cuboid": "box"}.get(ref.shape, ref.shape)


# ---- Issue 27, item 1: classes a user adds (a table is a value; problems keep theirs) --------

MUG = dict(dimensions=(0.12, 0.09, 0.10), sigma=(0.01, 0.01, 0.01), shape="cylinder")


def test_user_class_table_round_trip_and_default_unchanged(tmp_path):
    table = classes.DEFAULT_TABLE.with_class("mug", **MUG)
    assert table.names[: len(classes.CLASS_NAMES)] == classes.CLASS_NAMES
    assert table.index("mug") == len(classes.CLASS_NAMES)
    np.testing.assert_allclose(table.get("mug").dimensions, MUG["dimensions"])
    # The built-in table is a value: adding a class made a new table.
    assert classes.DEFAULT_TABLE.names == classes.CLASS_NAMES and "mug" not in classes.DEFAULT_TABLE
    mean, sigma = table.radii_table()
    np.testing.assert_allclose(mean[: len(classes.CLASSES)], classes.radii_table()[0])
    np.testing.assert_allclose(2 * mean[-1], MUG["dimensions"])
    np.testing.assert_allclose(2 * sigma[-1], MUG["sigma"])
    # Whole table through JSON, and the user's rows alone added to the built-in table.
    table.to_json(tmp_path / "all.json")
    assert classes.ClassTable.from_json(tmp_path / "all.json") == table
    classes.ClassTable(table.rows[-1:]).to_json(tmp_path / "mine.json")
    assert classes.ClassTable.from_json(tmp_path / "mine.json", base=classes.DEFAULT_TABLE) == table
    # No borrowed names: an existing name is refused unless replaced on purpose (index kept).
    with pytest.raises(ValueError, match="already in the table"):
        table.with_class("car", (1.0, 1.0, 1.0), (0.1, 0.1, 0.1))
    bigger = table.with_class("mug", (0.2, 0.2, 0.2), (0.02, 0.02, 0.02), replace=True)
    assert bigger.index("mug") == table.index("mug") and bigger.get("mug").dimensions == (0.2, 0.2, 0.2)


def test_class_file_not_utf8_or_too_large_is_named(tmp_path, monkeypatch):
    # Was the codec's bare "'utf-8' codec can't decode byte 0xe9", naming no file.
    path = tmp_path / "mine.json"
    path.write_bytes(b'{"classes": [{"name": "caf\xe9"}]}')
    with pytest.raises(ValueError, match=r"mine\.json: not a readable class table \(not UTF-8 text: byte 26\)"):
        classes.ClassTable.from_json(path)
    path.write_text('{"classes": []}')
    monkeypatch.setattr(classes, "_MAX_TABLE_BYTES", 8)
    with pytest.raises(ValueError, match=r"mine\.json: 15 bytes, more than a class table's 8"):
        classes.ClassTable.from_json(path)
    with pytest.raises(ValueError, match=r"nope\.json: cannot read the class table"):
        classes.ClassTable.from_json(tmp_path / "nope.json")


def test_class_json_mistakes_name_file_row_and_field(tmp_path):
    path = tmp_path / "bad.json"
    path.write_text('{"classes": [{"name": "mug", "dimensions": [0.1, 0.1, 0.1]}]}')
    with pytest.raises(ValueError, match=r"bad\.json: classes\[0\]\.sigma: missing"):
        classes.ClassTable.from_json(path)
    path.write_text('{"classes": [{"name": "mug", "dimensions": [0.1, -0.1, 0.1], "sigma": [1, 1, 1]}]}')
    with pytest.raises(ValueError, match=r"classes\[0\]: dimensions"):
        classes.ClassTable.from_json(path)
    path.write_text('{"classes": [{"name": "car", "dimensions": [1, 1, 1], "sigma": [1, 1, 1]}]}')
    with pytest.raises(ValueError, match="already in the table"):
        classes.ClassTable.from_json(path, base=classes.DEFAULT_TABLE)
    path.write_text("{not json")
    with pytest.raises(ValueError, match="bad.json: not valid JSON"):
        classes.ClassTable.from_json(path)


@pytest.mark.slow
def test_problem_keeps_its_table_and_solver_uses_its_prior():
    import jax

    from jaxsem import slam

    table = classes.DEFAULT_TABLE.with_class("mug", **MUG)
    K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])
    args = (K, (640, 480), np.eye(4)[None], [[300.0, 200.0, 340.0, 260.0]], [0], [0], ["mug"])
    with pytest.raises(ValueError, match="object_class: unknown class 'mug'"):
        slam.make_problem(*args)
    problem = slam.make_problem(*args, classes=table)
    assert problem.classes == table and int(problem.object_class[0]) == table.index("mug")
    # The shape prior is the mug's: zero residual at the mug's mean radii, not at another's.
    later = table.with_class("mug", (0.5, 0.5, 0.5), (0.05, 0.05, 0.05), replace=True)
    assert problem.classes != later  # a later table does not reach into the problem
    cfg = slam.SolverConfig()
    # jitted: op by op the initialisation and the residuals compiled some hundreds of programs
    est = jax.jit(slam.initialize)(problem, cfg)
    np.testing.assert_allclose(est.radii[0], np.array(MUG["dimensions"]) / 2)
    residual_blocks = jax.jit(slam.residual_blocks)
    shapes = residual_blocks(problem, est, cfg)[2]
    np.testing.assert_allclose(shapes, 0.0, atol=1e-12)
    est_big = slam.SlamEstimate(est.camera_T_world, est.rotation, est.center, est.radii * 2)
    assert float(np.abs(residual_blocks(problem, est_big, cfg)[2]).max()) > 1.0
    # Frames of the online smoother resolve names in the same table.
    frame = slam.make_frame(np.eye(4), [[300.0, 200.0, 340.0, 260.0]], ["mug"], [0], classes=table)
    assert int(frame.box_class[0]) == table.index("mug")
    with pytest.raises(ValueError, match="box_class: unknown class"):
        slam.make_frame(np.eye(4), [[300.0, 200.0, 340.0, 260.0]], ["mug"], [0])


def test_sequence_reader_reads_user_classes(tmp_path):
    import json

    from jaxsem import slam

    seq = {
        "K": [[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]],
        "image_size": [640, 480],
        "frames": [
            {
                "camera_T_world": np.eye(4).tolist(),
                "detections": [{"box": [300, 200, 340, 260], "class": "mug", "id": 0}],
            }
        ],
    }
    (tmp_path / "sequence.json").write_text(json.dumps(seq))
    with pytest.raises(ValueError, match="unknown class 'mug'"):
        slam.load_sequence(tmp_path)
    seq["classes"] = [{"name": "mug", **{k: list(v) if k != "shape" else v for k, v in MUG.items()}}]
    (tmp_path / "sequence.json").write_text(json.dumps(seq))
    loaded = slam.load_sequence(tmp_path)
    assert loaded.classes.names[-1] == "mug" and loaded.frames[0].classes == ("mug",)
    again = slam.load_sequence(slam.save_sequence(loaded, tmp_path / "copy"))
    assert again.classes == loaded.classes
