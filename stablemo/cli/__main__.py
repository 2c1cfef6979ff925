"""`python -m stablemo.cli ...`: the same as the `stablemo` console script."""

import sys

from stablemo.cli import main

sys.exit(main())
