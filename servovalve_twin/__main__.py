"""``python -m servovalve_twin``: the command line (``servovalve-twin``)."""

import sys

from .cli import main

sys.exit(main())
