"""VoluMon inference: ellipsoids from an image and boxes (or held-out synthetic images).

A thin wrapper: the code is ``jaxsem volumon predict``; ``--help`` lists the flags with their defaults, what
goes in and what comes out.
"""

import sys

from jaxsem.cli import command
from jaxsem.scripting import run_main

main = command("volumon predict")

if __name__ == "__main__":
    sys.exit(run_main(main))
