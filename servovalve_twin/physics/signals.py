"""The one table of the twin's signals: name, the paper's symbol, SI unit, meaning and the
subsystem that produces it. The topics (``nodes/topics.py``), the run table's columns
(``simulate``'s CSV/Parquet, :data:`~.plant.OUT_COLUMNS`), the Algorithm interface's signals,
the scenario's inputs and the outputs the monitor and the diagnosis compare are derived from it.

A new plant signal is one row here, its computation in the compiled loop and tick
(``physics/plant.py``) and its publication (``nodes/plant.py``).
"""

from __future__ import annotations

import dataclasses


@dataclasses.dataclass(frozen=True)
class Signal:
    name: str           # topic and column name
    symbol: str         # the paper's symbol
    unit: str           # SI
    meaning: str
    source: str         # the subsystem (node) that produces it
    ports: bool = False  # only valve models with port pressures (HD) produce it


#: every signal of a run, in the run table's column order
SIGNAL_TABLE: tuple[Signal, ...] = (
    Signal('com', 'Com', 'm', 'position command', 'command_generator'),
    Signal('fr', 'FR', 'N', 'external load (> 0 opposes +XJ)', 'load_supply'),
    Signal('psr', 'PSR', 'Pa', 'supply-return pressure', 'load_supply'),
    Signal('cor', 'Cor', 'A', 'servovalve current', 'ecu'),
    Signal('xs', 'XS', 'm', 'spool displacement', 'plant'),
    Signal('xj', 'XJ', 'm', 'jack position', 'plant'),
    Signal('dxj', 'DXJ', 'm/s', 'jack velocity', 'plant'),
    Signal('p12', 'P12', 'Pa', 'differential pressure P1 - P2', 'plant'),
    Signal('qj', 'QJ', 'm^3/s', 'working flow AJ*DXJ', 'plant'),
    Signal('p1', 'P1', 'Pa', 'port-1 absolute pressure', 'plant', ports=True),
    Signal('p2', 'P2', 'Pa', 'port-2 absolute pressure', 'plant', ports=True),
)
SIGNALS = {s.name: s for s in SIGNAL_TABLE}
#: every signal name, in order
NAMES: tuple[str, ...] = tuple(SIGNALS)
#: the scheduled inputs of a scenario
INPUTS: tuple[str, ...] = tuple(s.name for s in SIGNAL_TABLE
                                if s.source in ('command_generator', 'load_supply'))
#: the signals every valve model produces, and those only a model with ports does
COMMON: tuple[str, ...] = tuple(s.name for s in SIGNAL_TABLE if not s.ports)
PORTS: tuple[str, ...] = tuple(s.name for s in SIGNAL_TABLE if s.ports)
#: what a unit's sensors measure and the monitor, the diagnosis and progpy compare
MEASURED: tuple[str, ...] = ('xj', 'dxj', 'p12')


__all__ = ['Signal', 'SIGNAL_TABLE', 'SIGNALS', 'NAMES', 'INPUTS', 'COMMON', 'PORTS',
           'MEASURED']
