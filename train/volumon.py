"""Train VoluMon (thesis chapter 5) on the synthetic stereo set: a thin wrapper over
:func:`jaxsem.volumon.train_and_evaluate`.

A thin wrapper: the code is ``jaxsem volumon train``; ``--help`` lists the flags with their
defaults, what goes in and what comes out.
"""

import sys

from jaxsem.cli import command
from jaxsem.scripting import run_main

main = command("volumon train")

if __name__ == "__main__":
    sys.exit(run_main(main))
