"""A run's provenance record: what made it (valve model, scenario, parameters, control period),
written once by the twin into its bag and read once, here, by every command that takes a bag.

In an MCAP file it is the ``Metadata`` record named ``servovalve_twin`` (string values: the
scenario and the parameters as YAML). Storages without metadata records (sqlite3) may carry the
same keys in ``metadata.yaml``'s ``custom_data`` (rosbag2's user map, metadata version >= 6),
prefixed ``servovalve_twin.``. A bag may have been written or edited by someone else, so the
record is validated once on reading: anything malformed is one :class:`BagError` line.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any, Mapping

import yaml

from ..errors import BagError, TwinError
from ..physics.simulate import MAX_PERIOD
from . import safe_load

#: the shortest control period a provenance record may state [s]: a microsecond, below any
#: servo loop (a crafted 1e-300 s stepped a replayed algorithm at that period)
MIN_PERIOD = 1e-6

#: the MCAP metadata record's name, and the prefix of its keys in ``custom_data``
PROVENANCE = 'servovalve_twin'


@dataclasses.dataclass(frozen=True)
class Provenance:
    """A validated provenance record; ``Provenance()`` (falsy) is a bag without one."""

    valve_model: str | None = None
    control_period: float | None = None
    scenario_name: str | None = None
    scenario: dict[str, Any] | None = None      # Scenario.to_dict()
    params: dict[str, Any] = dataclasses.field(default_factory=dict)   # resolved parameters
    record: dict[str, str] = dataclasses.field(default_factory=dict)   # as stored
    #: the actuator's namespace ('' or '/left'): its topics are '/left/xj', ...
    namespace: str = ''

    def __bool__(self) -> bool:
        return bool(self.record)

    @classmethod
    def build(cls, valve_model: str, scenario, params, control_period: float, *,
              namespace: str = '') -> 'Provenance':
        """The record of a run the twin makes (``scenario`` a Scenario, ``params`` EhaParams)."""
        from .. import __version__
        record = {'package': 'servovalve_twin', 'version': __version__,
                  'valve_model': valve_model, 'control_period': repr(control_period),
                  'scenario_name': scenario.name,
                  'scenario': yaml.safe_dump(scenario.to_dict(), sort_keys=False),
                  'params': yaml.safe_dump(dict(params.resolved()), sort_keys=False)}
        if namespace.strip('/'):            # absent: the global namespace (older bags too)
            record['namespace'] = '/' + namespace.strip('/')
        return cls.from_record(record, 'the twin')

    @classmethod
    def from_record(cls, record: Mapping[str, Any], where: str | Path) -> 'Provenance':
        """Parse and validate a stored record; ``where`` names the bag in error messages."""
        if not record:
            return cls()
        bad = f'bag {str(where)!r}: its provenance record'
        rec = {str(k): v for k, v in record.items()}
        if any(not isinstance(v, str) for v in rec.values()):
            raise BagError(f'{bad} holds values that are not strings')
        cp = None
        if rec.get('control_period'):
            try:
                cp = float(rec['control_period'])
            except ValueError:
                cp = math.nan
            if not (math.isfinite(cp) and MIN_PERIOD <= cp <= MAX_PERIOD):
                raise BagError(f'{bad} has control_period {rec["control_period"]!r}; expected '
                               f'{MIN_PERIOD:g} to {MAX_PERIOD:g} s')
        params = _yaml_map(rec.get('params'), f'{bad} "params"')
        for k, v in params.items():
            if not (v is None or isinstance(v, (int, float, bool))):
                raise BagError(f'{bad} "params" gives {k} = {v!r}; expected numbers')
        scenario = _yaml_map(rec.get('scenario'), f'{bad} "scenario"') or None
        namespace = rec.get('namespace', '').rstrip('/')
        if namespace and (not namespace.startswith('/') or not all(
                part and (part[0].isalpha() or part[0] == '_')
                and all(c.isalnum() or c == '_' for c in part)
                for part in namespace[1:].split('/'))):
            raise BagError(f'{bad} has namespace {rec["namespace"][:80]!r}; expected an '
                           "absolute ROS namespace such as '/left'")
        out = cls(valve_model=rec.get('valve_model') or None, control_period=cp,
                  scenario_name=rec.get('scenario_name'), scenario=scenario, params=params,
                  record=rec, namespace=namespace)
        # validated now, once, so that no command meets a malformed record half-way through
        out.eha_params(where)
        out.scenario_object(where)
        return out

    def topic(self, name: str) -> str:
        """The bag's name of the twin's topic ``name`` ('xj' -> '/left/xj')."""
        return f'{self.namespace}/{name.lstrip("/")}'

    def to_record(self) -> dict[str, str]:
        """The record as it is stored (MCAP metadata)."""
        return dict(self.record)

    def eha_params(self, where: str | Path = 'the bag'):
        """The :class:`EhaParams` the run was made with: defaults for what the record does not
        list (a bag recorded before a parameter existed, or none at all)."""
        from ..physics.params import DEFAULTS, PARAM_NAMES
        values = {k: v for k, v in self.params.items() if k in PARAM_NAMES}
        try:
            # the record holds every parameter resolved: the derived ones equal to their
            # derivation derive again (EhaParams.derived_again)
            return DEFAULTS.replace(**values).derived_again()
        except TwinError as exc:
            raise BagError(f'bag {str(where)!r}: its recorded parameters are invalid: {exc}'
                           ) from None

    def scenario_object(self, where: str | Path = 'the bag'):
        """The recorded :class:`Scenario` (None without one), validated."""
        if self.scenario is None:
            return None
        from ..physics.scenario import scenario_from_dict
        try:
            return scenario_from_dict(self.scenario)
        except TwinError as exc:
            raise BagError(f'bag {str(where)!r}: its recorded scenario is invalid: {exc}'
                           ) from None


def _yaml_map(text: str | None, what: str) -> dict[str, Any]:
    if not text:
        return {}
    try:
        value = safe_load(text)
    except yaml.YAMLError:
        raise BagError(f'{what} is not readable YAML') from None
    except RecursionError:
        raise BagError(f'{what} is nested too deeply') from None
    if not isinstance(value, dict):
        raise BagError(f'{what} is {type(value).__name__}, expected a mapping')
    return value


def from_custom_data(custom: Any) -> dict[str, str]:
    """The record's keys out of ``metadata.yaml``'s ``custom_data`` ({} when it has none)."""
    if not isinstance(custom, dict):
        return {}
    prefix = PROVENANCE + '.'
    return {k[len(prefix):]: v for k, v in custom.items()
            if isinstance(k, str) and k.startswith(prefix)}


__all__ = ['PROVENANCE', 'Provenance', 'from_custom_data']
