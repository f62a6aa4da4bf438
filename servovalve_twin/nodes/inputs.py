"""A node's inputs: the lockstep queues (:class:`LockstepInputs`), the twin's in-process
delivery between its nodes (:class:`LocalBus`), and what is done with a value that is not
finite or out of its physical range."""

from __future__ import annotations

import math
from collections import deque
from typing import Callable

from rclpy.node import Node

#: physical bounds of an input topic: a value outside is dropped like a NaN (a 1e300 or negative
#: supply pressure would otherwise be integrated and published as P12 = +-1e300)
INPUT_LIMITS = {'psr': (0.0, 1.0e8)}


class LockstepInputs:
    """A node's Float64 inputs: the latest value of each (alone, a timer reads those) and, in
    the lockstep, a queue per input from which each tick takes exactly one value, in arrival
    order -- so callback order cannot change a result. With ``ticked`` the node also waits
    for the orchestrator to open the tick (:meth:`begin`) with its time and sub-step count.
    A non-finite value is logged and dropped, never used."""

    def __init__(self, node: Node, defaults: dict[str, float], *, lockstep: bool,
                 ticked: bool = True):
        self.node = node
        self.latest = dict(defaults)
        self.lockstep = lockstep
        self.ticked = ticked
        self.queues: dict[str, deque] = {n: deque() for n in defaults}
        self.ticks: deque[tuple[int, int]] = deque()
        self._limits = {n: INPUT_LIMITS.get(n, (-math.inf, math.inf)) for n in defaults}
        self._empty = len(self.queues)          # queues without a value (a tick needs none)

    def push(self, name: str, value: float) -> None:
        v = value if math.isfinite(value) else finite_or_none(value, name, self.node)
        if v is None:
            return
        lo, hi = self._limits[name]
        if not lo <= v <= hi:
            self.node.get_logger().error(f'ignored {name} = {v!r} outside [{lo:g}, {hi:g}]; '
                                         'keeping the last value', throttle_duration_sec=1.0)
            return
        self.latest[name] = v
        if self.lockstep:
            queue = self.queues[name]
            if not queue:
                self._empty -= 1
            queue.append(v)

    def begin(self, t_ns: int, n_sub: int) -> None:
        self.ticks.append((t_ns, n_sub))

    def pop(self) -> tuple[tuple[int, int] | None, dict[str, float]] | None:
        """The next complete tick, ``((t_ns, n_sub) or None, values)``, or None if incomplete."""
        if self._empty == 0 and (self.ticks or not self.ticked):
            tick = self.ticks.popleft() if self.ticked else None
            values = {n: q.popleft() for n, q in self.queues.items()}
            self._empty = sum(1 for q in self.queues.values() if not q)
            return tick, values
        return None


class LocalBus:
    """The twin's in-process delivery of Float64 values between its nodes.

    Every lockstep input would otherwise make a DDS round trip inside one process (publish,
    serialize, deliver, executor wake-up: ~12 us each, ~83 us per tick, bench/README.md). A
    value posted here is queued for each in-process subscriber and delivered by :meth:`drain`
    in posting order, one callback at a time -- the order the executor delivered in, so each
    node still consumes each input once and in order, and the run and its bag are unchanged.
    The topics are still published on DDS for the rest of the graph whenever something there
    subscribes (:meth:`TwinNode.emit`).
    """

    def __init__(self):
        self.routes: dict[str, list[Callable[[float], None]]] = {}
        self.queue: deque = deque()

    def subscribe(self, topic: str, callback: Callable[[float], None]) -> None:
        self.routes.setdefault(topic, []).append(callback)

    def post(self, topic: str, value: float) -> None:
        for callback in self.routes.get(topic, ()):
            self.queue.append((callback, value))

    def drain(self) -> None:
        """Deliver until nothing is queued (a delivery may post more: Cor, then P12...)."""
        queue = self.queue
        while queue:
            callback, value = queue.popleft()
            callback(value)


def finite_or_none(value: float, what: str, node: Node) -> float | None:
    """A received value if finite; a NaN/inf input is logged and dropped, never integrated."""
    if math.isfinite(value):
        return value
    node.get_logger().error(f'ignored non-finite {what} = {value!r}; keeping the last value',
                            throttle_duration_sec=1.0)
    return None


__all__ = ['INPUT_LIMITS', 'LockstepInputs', 'LocalBus', 'finite_or_none']
