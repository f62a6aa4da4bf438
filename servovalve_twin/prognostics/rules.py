"""The decision rules of diagnosis that its calibration and its onset search share, below
both: which catalog faults a simplified model can see, the sizes worth reporting, the evidence a
pair needs, and the calibration entry an onset answer takes. (They lived in diagnosis.py, which
calibration.py and onset.py then imported back: a circle.)"""

from __future__ import annotations

from typing import Any, Mapping

from ..physics.faults import FAULTS
from ..physics.params import PARAM_FIELDS

#: the catalog faults a simplified model can see (HD's geometry, e.g. clearance, it has not)
DIAGNOSABLE = tuple(n for n, f in FAULTS.items()
                    if PARAM_FIELDS[f.param].metadata['group'] != 'hd')
#: the smallest fault reported, as a fraction of the way from healthy to its alarm severity in
#: the fault's coordinate (:meth:`~..physics.faults.FaultSpec.to_g`), where the flight has no
#: calibration of its own (whose healthy units set the floor: :func:`above_floor`)
DETECTABLE = 0.2
#: how much lower (better) a pair's score must be than each of its two single faults' to be
#: reported: "very strong" evidence on Kass and Raftery's BIC scale
PAIR_EVIDENCE = 10.0
#: the calibration entry of answers refitted at an onset (:data:`.calibration_set.ONSET_UNITS`),
#: pooled over the onset flights; ``onset:<scenario>`` is one flight's own
ONSET_ENTRY = 'onset'


def fraction(fault: str, severity: float) -> float:
    """How far ``severity`` lies toward ``fault``'s alarm value, in its coordinate ``g``."""
    spec = FAULTS[fault]
    return abs(spec.to_g(severity)) / abs(spec.to_g(spec.demo))


def sized(fault: str, severity: float, share: float = DETECTABLE) -> bool:
    """``severity`` at least ``share`` (DETECTABLE) of the way from healthy to the fault's
    alarm value, in its coordinate."""
    return fraction(fault, severity) >= share


def above_floor(cal: Mapping[str, Any] | None, fault: str, severity: float) -> bool | None:
    """Whether ``severity`` lies beyond the verdict floor of a flight's own calibration
    (:mod:`.flight_calibration`; None: ``cal`` is none)."""
    if cal is None or 'verdict_fraction' not in cal:
        return None
    return bool(fraction(fault, severity) > cal['verdict_fraction'])


def onset_entry(cal: Mapping[str, Any] | None, scenario: str | None) -> str:
    """The calibration entry of an answer refitted at an onset on ``scenario``: the flight's
    own onset units' where the calibration has them, else those of every onset flight."""
    own = f'{ONSET_ENTRY}:{scenario}'
    return own if own in ((cal or {}).get('by_scenario') or {}) else ONSET_ENTRY


__all__ = ['DIAGNOSABLE', 'DETECTABLE', 'PAIR_EVIDENCE', 'ONSET_ENTRY', 'fraction', 'sized',
           'above_floor', 'onset_entry']
