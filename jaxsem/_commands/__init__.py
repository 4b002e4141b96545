"""The bodies of the ``jaxsem`` subcommands (private: :mod:`jaxsem.cli` dispatches to them and the
scripts in ``train/`` and ``infer/`` wrap them, so both run the same code).

Each module has ``build_parser(prog=None) -> argparse.ArgumentParser`` and
``main(argv=None, prog=None) -> int``; ``prog`` is the name shown in ``--help`` and in errors
(``None``: the script's file name, as argparse does). The table of subcommands is
``jaxsem.cli.COMMANDS``.
"""
