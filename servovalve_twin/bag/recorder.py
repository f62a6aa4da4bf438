"""The twin's recorder: every message its nodes publish, taken at the moment of publishing and
written with the tick's simulated time; Float64 values buffered and packed per topic."""

from __future__ import annotations

from typing import Any, Callable, Mapping

from .cdr import ENCODERS, encode_float64_value
from .writer import BagWriter


class Recorder:
    """``types``: topic as the graph names it ('/xj', '/left/xj') -> ROS type name
    ('std_msgs/msg/Float64').

    Takes every message the twin's nodes publish, at the moment they publish it (their
    ``tap``), and writes it to the bag with the tick's simulated time as log and publish time,
    as exact CDR wire bytes (:mod:`.bag.cdr`; the tests check them against raw subscriptions).
    Float64 values are buffered and packed per topic at each flush, every ``flush_ns`` of
    simulated time, so a killed run loses at most that much. The values are also what ``--out``
    writes as the CSV of the ROS run's own messages."""

    def __init__(self, writer: BagWriter | None, types: Mapping[str, str], *,
                 keep_values: bool, flush_ns: int = 50_000_000, namespace: str = ''):
        self.writer = writer
        #: the nodes' namespace ('' or '/left'): their relative topic 'xj' is '/left/xj' on
        #: the graph and in the bag (``types`` names topics as the graph does)
        self.namespace = namespace.rstrip('/')
        self.keep_values = keep_values
        self.now_ns = 0
        self.flush_ns = flush_ns
        self._flushed_ns = 0
        self.on_flush: Callable[[float], None] | None = None   # called with the flushed time
        #: live consumers of every message as (topic, CDR bytes, simulated time) -- the
        #: Foxglove view; empty by default, so recording pays nothing for them
        self.sinks: list[Callable[[str, bytes, int], None]] = []
        self.types = dict(types)
        self.encoders = {topic: ENCODERS[tn] for topic, tn in self.types.items()}
        float_topics = [t for t, tn in self.types.items() if tn == 'std_msgs/msg/Float64']
        # per Float64 topic: times and values not yet written; all of them when keep_values
        self._pending = {self._relative(t): ([], []) for t in float_topics}
        self.float_topics = tuple(self._pending)
        self._written = {t: 0 for t in self._pending}
        self._other = 0
        if writer is not None:
            for topic, type_name in self.types.items():
                writer.add_topic(topic, type_name)

    def _relative(self, name: str) -> str:
        """A graph name of ``types`` as the nodes name it: '/left/xj' -> 'xj'."""
        prefix = self.namespace + '/'
        return name[len(prefix):] if name.startswith(prefix) else name[1:]

    def _graph(self, topic: str) -> str:
        """A node's topic as the graph names it: 'xj' -> '/left/xj'; '/clock' stays."""
        return topic if topic[0] == '/' else f'{self.namespace}/{topic}'

    def record(self, topic: str, msg: Any) -> None:
        """The nodes' tap: ``topic`` as the node names it (relative: 'xj', or '/clock')."""
        if topic in self._pending:
            self.record_value(topic, msg.data)
        elif self.writer is None and not self.sinks:
            self._other += 1                  # nothing takes the bytes: do not encode them
        else:
            name = self._graph(topic)
            self.record_bytes(name, self.encoders[name](msg))

    def record_value(self, topic: str, value: float) -> None:
        """:meth:`record` for a Float64 topic's value (the nodes' ``tap_value``): no message."""
        if self.sinks:
            name = self._graph(topic)
            data = encode_float64_value(value)
            for sink in self.sinks:
                sink(name, data, self.now_ns)
        times, values = self._pending[topic]
        times.append(self.now_ns)
        values.append(value)

    def record_bytes(self, topic: str, data: bytes) -> None:
        """:meth:`record` of a message already encoded (a non-Float64 topic; relative names
        are taken as the nodes', in their namespace)."""
        name = self._graph(topic)
        for sink in self.sinks:
            sink(name, data, self.now_ns)
        if self.writer is not None:
            self.writer.write(name, data, self.now_ns)
        else:
            self._other += 1

    def tick_done(self) -> None:
        """Called after each tick: flush every ``flush_ns`` of simulated time."""
        if self.now_ns - self._flushed_ns >= self.flush_ns:
            self.flush()

    def flush(self) -> None:
        """Write the buffered Float64 values (if recording) and drop what is not kept: a long
        run without a bag or ``keep_values`` does not grow in memory."""
        self._flushed_ns = self.now_ns
        if self.writer is not None:        # every topic's values at once, in topic order
            self.writer.write_float64_many(
                [(self._graph(topic), times[self._written[topic]:],
                  values[self._written[topic]:])
                 for topic, (times, values) in self._pending.items()])
        for topic, (times, values) in self._pending.items():
            if self.keep_values:
                self._written[topic] = len(times)
            else:
                if self.writer is None:
                    self._other += len(times)
                times.clear()
                values.clear()
        if self.writer is None:
            return
        self.writer.flush()
        if self.on_flush is not None:
            self.on_flush(self.now_ns * 1e-9)

    def values(self, topic: str) -> tuple[list[int], list[float]]:
        return self._pending[topic]

    @property
    def count(self) -> int:
        """Messages recorded so far."""
        if self.writer is not None:
            return sum(self.writer.counts.values()) + sum(
                len(t) - self._written[k] for k, (t, _) in self._pending.items())
        return self._other + sum(len(t) for t, _ in self._pending.values())
