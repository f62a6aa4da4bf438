"""Progress on long work -- the report, sweeps, long runs: tqdm bars on standard error when it
is a terminal, nothing otherwise (pipes, CI logs, tests)."""

from __future__ import annotations

import sys
from typing import Any, Iterable


def enabled() -> bool:
    try:
        return sys.stderr.isatty()
    except (AttributeError, ValueError):
        return False


def progress(iterable: Iterable[Any] | None = None, *, total: int | None = None,
             desc: str = '', unit: str = 'it', initial: int = 0):
    """A tqdm bar over ``iterable`` (or one to ``update()`` by hand), disabled off a terminal."""
    from tqdm import tqdm
    return tqdm(iterable, total=total, desc=desc, unit=unit, disable=not enabled(), initial=initial,
                file=sys.stderr, leave=False, dynamic_ncols=True)
