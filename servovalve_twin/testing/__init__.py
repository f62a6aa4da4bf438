"""Deterministic bag replay into the nodes under test: :func:`replay_into`, and the pytest
fixtures (``ros_context``, ``replay``, ``twin_bag``) every test suite gets by installing this
package (entry point ``pytest11``: :mod:`.plugin`).

``replay_into(nodes, bag)`` delivers every selected recorded message to the nodes'
subscriptions in log-time order, one at a time, inside one executor, with simulated time set to
each message's log time first (the nodes run with ``use_sim_time``; their sim-time timers fire
in order as time passes, each at its own deadline counted from the bag's first message, a timer
due at t after the messages logged at t), and returns everything the nodes published,
keyed by topic, stamped with the simulated time at which it was published.

Why not DDS: ``ros2 bag play`` (and any player) races the node -- how many messages a callback
sees depends on the machine's load and the rate. Here nothing travels over DDS and nothing waits
on discovery or on the wall clock: a message is handed to the subscription's callback directly
(deserialized into the subscription's type, or as bytes for ``raw=True``), each callback runs to
completion before the next message, and what the nodes publish is captured at the publish call
and routed in-process to the other nodes under test that subscribe to it. The same bag and nodes
give the same outputs every run, on any machine.
"""

from __future__ import annotations

import copy
import inspect
import time
from pathlib import Path
from typing import Any, Iterable, Sequence

from rclpy.clock import ClockType
from rclpy.executors import SingleThreadedExecutor, TimeoutException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.serialization import deserialize_message
from rclpy.time import Time

from ..bag.anybag import open_any_bag
from ..errors import TwinError


class ReplayOutput(dict):
    """topic -> [(t_ns, msg), ...] of what the nodes published, in publication order."""

    def data(self, topic: str) -> list[Any]:
        """The ``data`` field of each message on ``topic`` (std_msgs scalars)."""
        return [m.data for _, m in self.get(topic, [])]

    def times(self, topic: str) -> list[int]:
        return [t for t, _ in self.get(topic, [])]


def replay_into(nodes: Node | Sequence[Node], bag: str | Path, *,
                topics: Iterable[str] | None = None, clock: bool = True,
                timeout_s: float = 600.0) -> ReplayOutput:
    """Replay ``bag`` into ``nodes`` (see the module docstring).

    :param topics: only these recorded topics (default: every topic some node subscribes to)
    :param clock: set simulated time to each message's log time (and fire sim-time timers at
        their deadlines); False delivers the messages without touching time
    :param timeout_s: wall-time guard against a node that never returns
    :returns: topic -> list of (simulated time [ns], message) the nodes published
    """
    nodes = [nodes] if isinstance(nodes, Node) else list(nodes)
    if not nodes:
        raise TwinError('replay_into needs at least one node')
    src = open_any_bag(bag)
    context = nodes[0].context
    if any(n.context is not context for n in nodes):
        raise TwinError('replay_into: every node must belong to the same rclpy context')
    r = _Replayer(nodes, clock, timeout_s)
    try:
        wanted = None if topics is None else {t if t.startswith('/') else '/' + t
                                              for t in topics}
        subscribed = r.subscribed_topics()
        play = [t for t in src.topics if (wanted is None or t in wanted) and t in subscribed
                and t != '/clock']
        if wanted is not None:
            missing = sorted(wanted - set(src.topics))
            if missing:
                raise TwinError(f'replay_into: the bag has no topic {missing[0]!r}; it has '
                                f'{sorted(src.topics)}')
        batch = None
        for topic, t_ns, data in src.messages(topics=play):
            if t_ns != batch:
                if batch is not None:
                    r.drain()          # what became ready at that time, after its messages
                r.advance_to(t_ns)
                batch = t_ns
            r.deliver(topic, data)
        r.drain()
        return r.outputs
    finally:
        r.close()


class _Replayer:
    def __init__(self, nodes: list[Node], clock: bool, timeout_s: float):
        self.nodes = nodes
        self.clock = clock
        self.deadline = time.monotonic() + timeout_s
        self.outputs = ReplayOutput()
        self.queue: list[tuple[str, Any]] = []
        self.now_ns: int | None = None
        self._wrapped: set[int] = set()
        self.executor = SingleThreadedExecutor(context=nodes[0].context)
        for n in nodes:
            if clock and not n.get_parameter('use_sim_time').value:
                n.set_parameters([Parameter('use_sim_time', Parameter.Type.BOOL, True)])
                # a timer made on wall time keeps its wall-time credit across the switch to
                # ROS time and rcl restores it at the first jump of the override, moving its
                # next call to that instant plus its period: the replay's first step (1 ms)
                # then shifted every firing by 1 ms and lost the last one. That jump is taken
                # here, before the replay resets the timers at the bag's first instant.
                for t in (0, 1):
                    n.get_clock().set_ros_time_override(Time(nanoseconds=t,
                                                             clock_type=ClockType.ROS_TIME))
            self.executor.add_node(n)
        self._wrap_publishers()

    def close(self) -> None:
        for n in self.nodes:
            self.executor.remove_node(n)
        self.executor.shutdown()

    # -- subscriptions ------------------------------------------------------------------
    def subscribed_topics(self) -> set[str]:
        return {s.topic_name for n in self.nodes for s in n.subscriptions}

    def deliver(self, topic: str, data: bytes | Any) -> None:
        """Hand one message to every subscription of ``topic`` among the nodes, in turn."""
        for n in self.nodes:
            for sub in list(n.subscriptions):
                if sub.topic_name != topic or topic == '/clock':
                    continue          # simulated time is set here, not by a time source
                if sub.raw:
                    msg = data if isinstance(data, bytes) else _serialize(data)
                else:
                    msg = (deserialize_message(data, sub.msg_type) if isinstance(data, bytes)
                           else copy.deepcopy(data))
                _call(sub.callback, msg)
                self._wrap_publishers()
                self._route()

    def _route(self) -> None:
        while self.queue:
            topic, msg = self.queue.pop(0)
            self.deliver(topic, msg)

    # -- publishers: captured at the publish call, stamped with the simulated time ---------
    def _wrap_publishers(self) -> None:
        for n in self.nodes:
            for pub in n.publishers:
                if id(pub) in self._wrapped or pub.topic_name in ('/rosout', '/parameter_events'):
                    continue
                self._wrapped.add(id(pub))
                pub.publish = self._capture(pub)

    def _capture(self, pub):
        topic = pub.topic_name

        def publish(msg):
            stamp = self.now_ns if self.now_ns is not None else 0
            kept = msg if isinstance(msg, bytes) else copy.deepcopy(msg)
            self.outputs.setdefault(topic, []).append((stamp, kept))
            self.queue.append((topic, kept))
        return publish

    # -- time -----------------------------------------------------------------------------
    def _set_time(self, t_ns: int) -> None:
        self.now_ns = t_ns
        if self.clock:
            for n in self.nodes:
                n.get_clock().set_ros_time_override(Time(nanoseconds=t_ns,
                                                         clock_type=ClockType.ROS_TIME))

    def advance_to(self, t_ns: int) -> None:
        """Fire every sim-time timer due before ``t_ns``, each at its own deadline and in
        order, then set the time to ``t_ns``. Timers due exactly at ``t_ns`` run after the
        messages logged at ``t_ns`` (data stamped t is there at t)."""
        if self.clock and self.now_ns is not None:
            for _ in range(10_000_000):
                due = self._next_timer_deadline()
                if due is None or due >= t_ns:
                    break
                self._set_time(due)
                self.drain()
        if self.now_ns is None:
            # simulated time starts at the bag's first message: the nodes' sim-time timers,
            # created before any time was set, count their periods from there
            self._set_time(t_ns)
            if self.clock:
                for n in self.nodes:
                    for timer in n.timers:
                        if timer.clock.clock_type == ClockType.ROS_TIME:
                            timer.reset()
        elif t_ns > self.now_ns:
            self._set_time(t_ns)

    def _next_timer_deadline(self) -> int | None:
        """The earliest deadline after now of the nodes' sim-time timers (None: no timer)."""
        best = None
        for n in self.nodes:
            for timer in n.timers:
                if timer.is_canceled() or timer.clock.clock_type != ClockType.ROS_TIME:
                    continue
                left = timer.time_until_next_call()
                if left is not None and left > 0:
                    due = self.now_ns + int(left)
                    best = due if best is None else min(best, due)
        return best

    def drain(self) -> None:
        """Run every ready callback (timers, services...) until none is left."""
        while True:
            if time.monotonic() > self.deadline:
                raise TwinError('replay_into: timed out (a node keeps itself busy?)')
            try:
                handler, _, _ = self.executor.wait_for_ready_callbacks(timeout_sec=0.0)
            except TimeoutException:
                return
            handler()
            exc = handler.exception()
            if exc is not None:
                raise exc
            self._wrap_publishers()
            self._route()


def _call(callback, msg) -> None:
    try:            # required positional parameters only (a lambda m, n=name: has one)
        n = sum(1 for p in inspect.signature(callback).parameters.values()
                if p.default is p.empty and p.kind in (p.POSITIONAL_ONLY,
                                                       p.POSITIONAL_OR_KEYWORD))
    except (TypeError, ValueError):
        n = 1
    if n >= 2:                      # callback(msg, message_info): no DDS, no info to give
        callback(msg, None)
    else:
        callback(msg)


def _serialize(msg) -> bytes:
    from rclpy.serialization import serialize_message
    return serialize_message(msg)


__all__ = ['replay_into', 'ReplayOutput']
