"""`python -m mop ...` (and `torchrun --nproc_per_node N -m mop train ...`) run the `mop` command."""

import sys

from mop.cli import main

sys.exit(main())
