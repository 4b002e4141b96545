"""Convenience flags generated from config dataclasses (``scripting.add_config_flags``), beside ``--set``."""

import argparse
import dataclasses
import importlib

import pytest

from jaxsem import cli, config as jcfg, scripting as sc
from jaxsem.scripting._config_flags import config_flags  # layers: white-box

# Commands that offer convenience flags for config fields, and a few flags each must keep.
EXPECTED = {
    "volumon train": ["--steps", "--batch-size", "--lr", "--num-train", "--seed", "--checkpoint-every"],
    "lsd train": ["--stage1-steps", "--stage2-steps", "--batch-size", "--learning-rate", "--eval-every", "--seed"],
    "lsd data": ["--samples-per-building", "--goals-per-moment", "--sample-prob", "--nav-samples"],
    "lsd plan": ["--n", "--max-steps"],
    "roshan": ["--box-sigma", "--texture-sigma", "--default-depth"],
}


def _parsers():
    for words, module_name, _ in cli.COMMANDS:
        module = importlib.import_module(f"jaxsem._commands.{module_name}")
        yield " ".join(words), module.build_parser(prog=f"jaxsem {' '.join(words)}")


def _field_default(cls, dotted):
    value = cls()
    for name in dotted.split("."):
        value = jcfg.fields(value)[name]
    return value


def test_every_convenience_flag_is_a_config_field_and_help_shows_its_default():
    seen = {}
    for name, parser in _parsers():
        help_text = " ".join(parser.format_help().split())
        for cls, flags in config_flags(parser):
            for flag in flags:
                _field_default(cls, flag.field)  # a real field (KeyError otherwise)
                action = parser._option_string_actions[flag.flag]
                assert action.dest == flag.dest
                shown = "the preset's" if action.default is None else repr(action.default)
                assert f"config field {flag.field}: " in help_text, (name, flag)
                assert f"(default: {shown})" in " ".join(sc.HelpFormatter("x")._get_help_string(action).split())
                seen.setdefault(name, []).append(flag.flag)
    for name, flags in EXPECTED.items():
        assert set(flags) <= set(seen.get(name, [])), (name, seen.get(name))


def test_every_command_with_config_flags_has_one_generated_set():
    with_flags = set()
    for name, parser in _parsers():
        if config_flags(parser):
            with_flags.add(name)
            sets = [a for a in parser._actions if "--set" in a.option_strings]
            assert len(sets) == 1 and sets[0].dest == "set", name
    assert set(EXPECTED) <= with_flags


@dataclasses.dataclass(frozen=True)
class _Inner:
    """A nested config.

    Attributes:
      depth: metres
        in front of the camera.
    """

    depth: float = 2.0


@dataclasses.dataclass(frozen=True)
class _Toy:
    """A toy config.

    Attributes:
      steps, rate: optimiser settings.
    """

    steps: int = 10
    rate: float = 0.1
    name: str = "a"  # what the run is called
    flag: bool = False
    """Whether to do it."""
    inner: _Inner = _Inner()
    note: int = dataclasses.field(default=0, metadata={"help": "from the metadata"})

    def __post_init__(self):
        if self.steps > 100:
            raise ValueError(f"steps: expected <= 100, got {self.steps}")


def _toy_parser(base=None):
    parser = argparse.ArgumentParser(formatter_class=sc.HelpFormatter)
    flags = sc.add_config_flags(
        parser,
        _Toy,
        ["steps", sc.ConfigFlag("rate", "--lr", sc.positive_float), "name", "flag", "inner.depth", "note"],
        base=base,
    )
    return parser, flags


def test_flags_take_type_and_help_from_the_dataclass():
    parser, flags = _toy_parser()
    assert [f.flag for f in flags] == ["--steps", "--lr", "--name", "--flag", "--depth", "--note"]
    text = " ".join(parser.format_help().split())
    for piece in [
        "config field steps: optimiser settings (default: the preset's)",
        "config field name: what the run is called",
        "config field flag: Whether to do it",
        "config field inner.depth: metres in front of the camera",
        "config field note: from the metadata",
    ]:
        assert piece in text
    args = parser.parse_args(["--steps", "5", "--lr", "0.5", "--flag", "yes", "--depth", "3"])
    cfg = sc.apply_config_flags(_Toy(), args, flags)
    assert cfg == _Toy(steps=5, rate=0.5, flag=True, inner=_Inner(depth=3.0))
    assert sc.apply_config_flags(_Toy(), parser.parse_args([]), flags) == _Toy()


@pytest.mark.parametrize("argv", [["--steps", "2.5"], ["--lr", "-1"], ["--flag", "maybe"], ["--depth", "nan"]])
def test_flags_reject_bad_text_naming_the_flag(argv, capsys):
    parser, _ = _toy_parser()
    with pytest.raises(SystemExit):
        parser.parse_args(argv)
    assert argv[0] in capsys.readouterr().err


def test_config_checks_and_set_go_through_one_path():
    parser, flags = _toy_parser()
    with pytest.raises(sc.UsageError, match="^--steps: steps: expected <= 100"):
        sc.apply_config_flags(_Toy(), parser.parse_args(["--steps", "500"]), flags)
    with pytest.raises(sc.UsageError, match="^--set: .*unknown config field 'bogus'"):
        sc.apply_config_flags(_Toy(), parser.parse_args([]), flags, ["bogus=1"])
    # --set comes after the flags
    cfg = sc.apply_config_flags(_Toy(), parser.parse_args(["--steps", "5"]), flags, ["steps=7"])
    assert cfg.steps == 7
    # the parser's own --set (added once with the flags) is read when no list is given
    args = parser.parse_args(["--steps", "5", "--set", "steps=8", "--set", "inner.depth=4"])
    assert sc.apply_config_flags(_Toy(), args, flags) == _Toy(steps=8, inner=_Inner(depth=4.0))
    with pytest.raises(sc.UsageError, match="^--set: .*'bogus'"):
        sc.apply_config_flags(_Toy(), parser.parse_args(["--set", "bogus=1"]), flags)


def test_a_fixed_base_is_the_default_and_shown():
    parser, flags = _toy_parser(base=_Toy(steps=42))
    args = parser.parse_args([])
    assert args.steps == 42
    assert "(default: 42)" in " ".join(parser.format_help().split())
    assert sc.apply_config_flags(_Toy(), args, flags).steps == 42


def test_unknown_or_undocumented_fields_are_refused():
    with pytest.raises(ValueError, match="no config field 'nope'"):
        sc.add_config_flags(argparse.ArgumentParser(), _Toy, ["nope"])

    @dataclasses.dataclass(frozen=True)
    class Bare:
        x: int = 1

    with pytest.raises(ValueError, match="documents nothing"):
        sc.add_config_flags(argparse.ArgumentParser(), Bare, ["x"])
    parser = argparse.ArgumentParser()
    sc.add_config_flags(parser, Bare, [sc.ConfigFlag("x", help="given by the command")])
    assert "given by the command" in parser.format_help()
