"""Fixtures shared by the integration tests that render an LSD building."""

import dataclasses

import pytest

from jaxsem import planning
from jaxsem.planning._buildings import TRAIN_PARAMS  # layers: white-box

TINY = dataclasses.replace(
    TRAIN_PARAMS,
    width=(10.0, 11.0),
    depth=(7.0, 8.0),
    margin=2.0,
    room_size=(3.0, 4.0),
    deep_block=20.0,
)


@pytest.fixture(scope="module")
def building():
    """A tiny train-family building (seed 0, about 10 m x 7 m), one per test module."""
    return planning.generate_building(0, "train", params=TINY)
