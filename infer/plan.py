"""Online navigation with the LSD sampler and/or the uniform PRM on one map; saves figures.

A thin wrapper: the code is ``jaxsem lsd plan``; ``--help`` lists the flags with their defaults, what
goes in and what comes out.
"""

import sys

from jaxsem.cli import command
from jaxsem.scripting import run_main

main = command("lsd plan")

if __name__ == "__main__":
    sys.exit(run_main(main))
