"""`python -m pcv_sim` is `pcv-sim`."""

import sys

from pcv_sim.cli import main

sys.exit(main())
