"""`python -m imitation …`, and so `torchrun … -m imitation …`: the command line, as `imitation …` runs it."""

import sys

from cli import main

sys.exit(main())
