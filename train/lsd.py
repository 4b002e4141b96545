"""Trains the LSD network in two stages on expert shards (thin wrapper over jaxsem.lsd).

A thin wrapper: the code is ``jaxsem lsd train``; ``--help`` lists the flags with their defaults, what
goes in and what comes out.
"""

import sys

from jaxsem.cli import command
from jaxsem.scripting import run_main

main = command("lsd train")

if __name__ == "__main__":
    sys.exit(run_main(main))
