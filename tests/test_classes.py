"""One class table: every part of jaxsem that knows an object's size reads jaxsem.classes."""

import numpy as np
import pytest

from jaxsem import classes, factors, sim


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
    from jaxsem.data import DEFAULT_CLASSES

    for c in DEFAULT_CLASSES:
        ref = classes.get(c.name)
        np.testing.assert_allclose(c.extents, ref.dimensions)
        assert c.shape == {"cuboid": "box"}.get(ref.shape, ref.shape)
