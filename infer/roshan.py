"""ROSHAN online object SLAM over a posed detection sequence (or a simulated one).

A thin wrapper: the code is ``jaxsem roshan``; ``--help`` lists the flags with their defaults, what
goes in and what comes out.
"""

import sys

from jaxsem.cli import command
from jaxsem.scripting import run_main

main = command("roshan")

if __name__ == "__main__":
    sys.exit(run_main(main, prog="infer/roshan.py"))
