"""One configuration style: presets, files and key=value overrides for any frozen config."""

import argparse
import dataclasses
from typing import NamedTuple, Optional

import equinox as eqx
import pytest

from jaxsem import config as cfg


@dataclasses.dataclass(frozen=True)
class Loss:
    primal_weight: float = 1.0
    power: int = 1


@dataclasses.dataclass(frozen=True)
class Train:
    steps: int = 100
    lr: float = 1e-3
    name: str = "run"
    use_noise: bool = False
    sizes: tuple = (64, 64)
    limit: Optional[int] = None
    loss: Loss = Loss()


class Solver(eqx.Module):
    max_steps: int = 50
    rtol: float = 1e-5
    loss: str = eqx.field(static=True, default="l2")

    def __check_init__(self):
        if self.loss not in ("l2", "cauchy"):
            raise ValueError(f"loss: expected l2 or cauchy, got {self.loss!r}")


class Sim(NamedTuple):
    frames: int = 60
    noise: float = 3.0


PRESETS = cfg.Presets(Train)


@PRESETS.register("tiny")
def _tiny(c):
    return cfg.override(c, steps=2, sizes=(8, 8))


def test_override_by_dotted_name_parses_types():
    c = cfg.override(
        Train(),
        ["steps=7", "lr=3e-4", "loss.primal_weight=0.5", "use_noise=true", "sizes=32,48", "limit=5", "name=abc"],
    )
    assert c == Train(steps=7, lr=3e-4, name="abc", use_noise=True, sizes=(32, 48), limit=5, loss=Loss(0.5, 1))
    assert cfg.override(c, {"limit": "none"}).limit is None


@pytest.mark.parametrize(
    "change, match",
    [
        ("stepz=3", "unknown config field 'stepz'.*steps"),
        ("steps=abc", "steps: cannot read 'abc' as int"),
        ("loss.x=1", "unknown config field 'x'"),
        ("steps", "expected key=value"),
        ("lr.a=1", "not a nested config"),
    ],
)
def test_bad_overrides_name_the_field(change, match):
    with pytest.raises(ValueError, match=match):
        cfg.override(Train(), [change])


def test_equinox_and_namedtuple_configs():
    assert cfg.override(Solver(), ["max_steps=9"]).max_steps == 9
    # a static field is no leaf of the pytree: it is set all the same, the config's checks run
    changed = cfg.override(Solver(), ["loss=cauchy", "rtol=1e-3"])
    assert (changed.loss, changed.rtol, changed.max_steps) == ("cauchy", 1e-3, 50)
    with pytest.raises(ValueError, match="loss: expected"):
        cfg.override(Solver(), ["loss=tukey"])
    assert cfg.override(Sim(), {"noise": "1.5"}) == Sim(60, 1.5)


def test_presets_files_and_round_trip(tmp_path):
    assert PRESETS["tiny"].steps == 2 and PRESETS["default"] == Train()
    with pytest.raises(ValueError, match="unknown preset.*tiny"):
        PRESETS["huge"]
    c = cfg.override(PRESETS["tiny"], ["loss.power=2"])
    path = cfg.save(c, tmp_path / "c.json")
    assert cfg.load(Train, path) == c
    assert PRESETS.resolve(str(path)) == c
    (tmp_path / "bad.json").write_text('{"steps": 3, "typo": 1}')
    with pytest.raises(ValueError, match="bad.json.*unknown field.*typo"):
        PRESETS.resolve(str(tmp_path / "bad.json"))
    (tmp_path / "broken.json").write_text("{")
    with pytest.raises(ValueError, match="broken.json: not valid JSON"):
        cfg.load(Train, tmp_path / "broken.json")


def test_command_line_arguments():
    parser = argparse.ArgumentParser()
    cfg.add_config_arguments(parser, PRESETS)
    args = parser.parse_args(["--config", "tiny", "--set", "lr=0.1", "--set", "loss.primal_weight=2"])
    c = cfg.config_from_args(args, PRESETS)
    assert (c.steps, c.lr, c.loss.primal_weight) == (2, 0.1, 2.0)
