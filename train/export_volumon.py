"""Export a VoluMon training run as the shipped model (weights, config, learning-curve figure).

A thin wrapper: the code is ``jaxsem volumon export``; ``--help`` lists the flags with their defaults, what
goes in and what comes out.
"""

import sys

from jaxsem.cli import command
from jaxsem.scripting import run_main

main = command("volumon export")

if __name__ == "__main__":
    sys.exit(run_main(main))
