"""``python -m servovalve_twin.cli``: the command line."""

import sys

from . import main

sys.exit(main())
