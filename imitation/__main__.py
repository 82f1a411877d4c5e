"""`python -m imitation …`, and so `torchrun … -m imitation …`: the command line, as `imitation …` runs it."""

import sys

from cli import main

if __name__ == "__main__":  # a spawned process (the sweep's Tune) imports this module again
    sys.exit(main())
