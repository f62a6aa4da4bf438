"""Numbers read from a scenario or a sensors section (a file, a bag's provenance, a live
parameter): one parser for both, below both (it lived in scenario.py, which sensors.py then
imported back while scenario.py imported sensors.py: a circle)."""

from __future__ import annotations

import math
from typing import Any

from ..errors import ScenarioError


def number(value: Any, where: str) -> float:
    """A finite float from a number or a numeric string (YAML 1.1 reads ``2e-13`` as text)."""
    if isinstance(value, bool):
        raise ScenarioError(f'{where}: expected a number, got {short(value)}')
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ScenarioError(f'{where}: expected a number, got {short(value)}') from None
    if not math.isfinite(x):
        raise ScenarioError(f'{where}: expected a finite number, got {short(value)}')
    return x


def short(value: Any, limit: int = 120) -> str:
    """A value's repr for an error line, cut to ``limit`` characters."""
    text = repr(value)
    return text if len(text) <= limit else text[:limit] + f'... ({len(text)} characters)'


__all__ = ['number', 'short']
