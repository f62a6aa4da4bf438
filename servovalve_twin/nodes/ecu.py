"""The ECU node: the position loop Cor = sat(GAP*(Com - XJ), CorM)."""

from __future__ import annotations

from typing import Sequence

from ..physics.ecu import EcuLaw
from ..physics.params import EhaParams
from .base import TwinNode
from .process import spin_standalone


class Ecu(TwinNode):
    """Position loop of the EHA.

    Subscribes: ``com`` (std_msgs/Float64, m), ``xj`` (std_msgs/Float64, m).
    Publishes: ``cor`` (std_msgs/Float64, A).
    Parameters: the ECU's own, ``GAP`` (double, A/m) and ``CorM`` (double, A), and
    ``control_period`` (double, s, read-only).

    Alone, a timer computes Cor every ``control_period`` from the latest Com and XJ (0 m until
    the first messages arrive). In the lockstep it computes once per tick, when that tick's
    Com and XJ have both arrived.
    """

    subsystem = 'ecu'

    def __init__(self, **kwargs):
        super().__init__('ecu', **kwargs)
        # the control law is the physics layer's (the source of the compiled one simulate runs)
        self.law = EcuLaw(self.params)
        self.add_publishers(['cor'])
        self.start_inputs({'com': 0.0, 'xj': 0.0}, ticked=False)
        self.start()

    def on_params(self, params: EhaParams) -> None:
        self.law = EcuLaw(params)

    def step(self, tick, values: dict[str, float]) -> None:
        self.emit_value('cor', self.law(values['com'], values['xj']))

    def on_timer(self) -> None:
        self.emit_value('cor', self.law(self.io.latest['com'], self.io.latest['xj']))


def main(args: Sequence[str] | None = None) -> int:
    return spin_standalone(Ecu, args)
