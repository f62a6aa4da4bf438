"""``python -m servovalve_twin``: the command line (``servovalve-twin``)."""

import sys

from .entry import one_blas_thread

one_blas_thread()
from .cli import main  # noqa: E402 -- after the BLAS setting, which must precede numpy

sys.exit(main())
