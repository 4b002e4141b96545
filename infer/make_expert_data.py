"""Generates the LSD expert dataset (thesis 3.3.2) as compressed npz shards, one per building.

A thin wrapper: the code is ``jaxsem lsd data``; ``--help`` lists the flags with their defaults, what
goes in and what comes out.
"""

import sys

from jaxsem.cli import command
from jaxsem.scripting import run_main

main = command("lsd data")

if __name__ == "__main__":
    sys.exit(run_main(main))
