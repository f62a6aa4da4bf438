"""A twin's place on the ROS graph: its executor (:data:`EXECUTORS`) and its simulated time
(:class:`GraphClock`): ``/clock`` published by the
twin that owns it, or followed from another owner; pacing to a real-time factor; the owner's
wait for its followers; and the executor's turns, which end at a message the turn itself sent.

One ``/clock`` per graph, one owner: several actuators (twins in their own namespaces) share one
simulated time by following the owner -- a follower runs each tick once ``/clock`` has reached
it, so its results do not depend on the owner's pace.
"""

from __future__ import annotations

import sys
import time
from typing import Callable

from rclpy.duration import Duration
from rclpy.context import Context
from rclpy.exceptions import InvalidNamespaceException
from rclpy.executors import SingleThreadedExecutor
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.task import Future
from rclpy.validate_namespace import validate_namespace
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Empty

from ..errors import TwinError
from ..nodes.topics import QOS

#: the longest wait for a turn of the executor
TICK_DEADLINE_S = 5.0
#: the longest sleep between two looks at a stop request (pacing, following)
PACE_SLICE_S = 0.05
#: following: how often (wall) a twin waiting for /clock checks that the owner is still there
OWNER_CHECK_S = 2.0
#: the clock owner at the end: after this long waiting for its last /clock to be acknowledged
#: it says so; it gives up after CLOCK_ACK_MAX_S (a reader whose process is stopped, not gone:
#: DDS drops a vanished one after its lease, 20 s with Fast DDS's default)
CLOCK_ACK_S = 2.0
CLOCK_ACK_MAX_S = 30.0
#: how long the /clock owner waits for its --followers before it gives up (wall seconds):
#: a follower that never comes (a typo in its namespace, a crash) held the owner for ever
FOLLOWERS_WAIT_S = 300.0
#: a /clock owner that finds another within this long after it started refuses to run
NEWCOMER_S = 10.0
#: /clock from its owner: the latest time is all that counts, and a follower that joins late
#: (discovery) is handed it at once (transient local); rclpy's time sources (best effort,
#: volatile) match it
CLOCK_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                       reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL)


def _events_executor(*, context: Context):
    """rclpy's EventsExecutor calls ``faulthandler.enable()`` on ``sys.stderr``, which fails
    where stderr is not a real file (Jupyter, pytest's capture): hand it the process's own."""
    try:
        sys.stderr.fileno()
        return EventsExecutor(context=context)
    except (AttributeError, OSError, ValueError):
        saved, sys.stderr = sys.stderr, sys.__stderr__
        try:
            return EventsExecutor(context=context)
        finally:
            sys.stderr = saved


#: rclpy's EventsExecutor was measured 8x cheaper per tick than the SingleThreadedExecutor
#: here (bench/bench_twin.py); the latter is kept for comparison.
EXECUTORS = {'events': _events_executor, 'single': SingleThreadedExecutor}


class GraphClock:
    """``/clock`` for one twin, on its ``twin_clock`` node.

    :param follow: follow another owner's /clock instead of publishing it
    :param real_time_factor: pace simulated time to it (None: as fast as possible)
    :param followers: the owner starts once this many following twins are on the graph
    :param namespace: the twin's namespace ('' or '/left'), to tell its followers from itself
    :param stopped: whether a stop was requested (checked while waiting)
    """

    def __init__(self, node: Node, *, follow: bool, real_time_factor: float | None,
                 followers: int, namespace: str, stopped: Callable[[], bool]):
        self.node = node
        self.follow = follow
        self.real_time_factor = real_time_factor
        self.followers = followers
        self.namespace = namespace
        self.stopped = stopped
        self.executor = None            # set by the twin once its executor exists
        self.pub = None if follow else node.create_publisher(Clock, '/clock', CLOCK_QOS)
        self.owner_ns = -1              # the latest /clock seen (the owner's, following)
        self.published_ns = -1          # the last /clock published on DDS
        self.turned_ns = -1             # ... and taken by the executor
        #: a node outside the twin subscribes to /clock (refreshed at every turn)
        self.wanted = True
        self._owner_checked = -float('inf')     # the last look for another /clock owner
        self._born = time.perf_counter()
        self._warned_owner = False
        self._turn: Future | None = None
        node.create_subscription(Clock, '/clock', self._on_clock, CLOCK_QOS if follow else QOS)
        if follow:
            # a follower's turns end at a message to itself on a hidden topic (no /clock of
            # its own to wait on; EventsExecutor takes no guard condition)
            self._turn_pub = node.create_publisher(Empty, '~/_turn', QOS)
            node.create_subscription(Empty, '~/_turn', self._on_turn, QOS)

    # -- before and at a tick ----------------------------------------------------------------
    def other_owners(self) -> list[str]:
        """The nodes besides this twin's that publish /clock (a graph has one owner)."""
        me = (self.node.get_name(), self.node.get_namespace())
        # (a publisher discovered before its node's name says _NODE_NAME_UNKNOWN_)
        return sorted('a node not named yet' if 'UNKNOWN' in i.node_name else
                      f'{i.node_namespace.rstrip("/")}/{i.node_name}'
                      for i in self.node.get_publishers_info_by_topic('/clock')
                      if (i.node_name, i.node_namespace) != me)

    def check_single_owner(self) -> None:
        """The owner beside another publisher of /clock (two owners made every use_sim_time
        node's time jump between them): within its first :data:`NEWCOMER_S` of wall time the
        twin is the newcomer and refuses to go on; later the other is, and it warns once (so
        that the owner already running is not stopped by one that is about to step down)."""
        if self.pub is None or self._warned_owner:
            return
        others = self.other_owners()
        if not others:
            return
        what = (f'another node publishes /clock on this graph ({", ".join(others)}): a graph '
                'has one /clock owner')
        if time.perf_counter() - self._born < NEWCOMER_S:
            raise TwinError(f'{what}; run this twin with --clock follow, or stop the other')
        self._warned_owner = True
        self.node.get_logger().warning(f'{what}; nodes on use_sim_time see both')

    def before(self, t_ns: int, wall0: float, on_clock_period: bool) -> None:
        """Wait until tick ``t_ns`` may run: following, until /clock has reached it; paced,
        until the wall clock has (``wall0``: the run's start, perf_counter seconds). The
        owner looks for a second /clock owner every OWNER_CHECK_S of wall time."""
        if self.pub is not None:
            now = time.perf_counter()
            if now - self._owner_checked >= OWNER_CHECK_S:
                self._owner_checked = now
                self.check_single_owner()
        if self.follow and t_ns > self.owner_ns:
            self._wait_for_clock(t_ns)
        elif self.real_time_factor is not None and on_clock_period:
            self._pace(wall0 + t_ns * 1e-9 / self.real_time_factor)

    def publish(self, t_ns: int, msg: Clock, turn_due: bool) -> None:
        """/clock on DDS: at every turn of the executor, and every clock period while a node
        outside the twin listens or the run is paced for one."""
        if self.pub is not None and (self.wanted or self.real_time_factor is not None
                                     or turn_due):
            self.published_ns = t_ns
            self.pub.publish(msg)

    def refresh(self, own_subscribers: int) -> None:
        """Whether something beyond the twin's own ``own_subscribers`` listens to /clock."""
        if self.pub is not None:
            self.wanted = self.pub.get_subscription_count() > own_subscribers

    def take_turn(self, k: int) -> None:
        """Let the executor handle everything that has arrived -- the nodes' /clock,
        parameter requests and their responses -- in one call, until it takes the message
        that marks the turn's end (the last /clock published; following, a message to
        itself): the executor delivers in arrival order, so all that came before is done."""
        if self.follow:
            self._turn = Future()
            self._turn_pub.publish(Empty())
            what = 'its turn'
        elif self.published_ns == self.turned_ns:
            return                      # that /clock was taken at the previous turn
        else:
            self._turn = Future()
            what = f'/clock at {self.published_ns * 1e-9:.3f} s'
        self.executor.spin_until_future_complete(self._turn, timeout_sec=TICK_DEADLINE_S)
        if not self._turn.done():
            raise TwinError(f'tick {k}: the executor did not take {what} within '
                            f'{TICK_DEADLINE_S} s')
        self._turn = None
        self.turned_ns = self.published_ns

    def finish(self) -> None:
        """The owner at the end: its followers' last tick waits for the last /clock, so see
        it acknowledged by every reader before the publisher goes. A follower that lags (a
        busy machine) may take seconds; a fixed wait let the owner leave first and the
        follower stop short of its end. Bounded: a reader that leaves the graph no longer
        counts, after :data:`CLOCK_ACK_MAX_S` the owner warns and goes, and a stop request
        (SIGINT) ends the wait within one slice -- the followers then see the owner go and
        stop there too, as the user asked."""
        if self.pub is None or not self.wanted:
            return
        start = time.perf_counter()
        said = False
        while not self.pub.wait_for_all_acked(Duration(seconds=PACE_SLICE_S)):
            if self.stopped():
                return
            waited = time.perf_counter() - start
            if waited >= CLOCK_ACK_MAX_S:
                self.node.get_logger().warning(
                    f'the last /clock ({self.published_ns * 1e-9:.3f} s) was not '
                    f'acknowledged by every reader within {waited:.0f} s: leaving anyway')
                return
            if not said and waited >= CLOCK_ACK_S:
                said = True
                self.node.get_logger().info(
                    f'waiting for the last /clock ({self.published_ns * 1e-9:.3f} s) to '
                    f'reach every reader ({self.pub.get_subscription_count()} subscriptions)')

    # -- waiting ------------------------------------------------------------------------------
    def wait_for_followers(self) -> None:
        """The owner: wait (until stopped) for ``followers`` twins following /clock, each
        known by its ``twin_clock`` node in a namespace other than this twin's."""
        said = False
        start = time.monotonic()
        while self.followers and not self.stopped():
            found = {i.node_namespace for i in self.node.get_subscriptions_info_by_topic(
                '/clock') if i.node_name == 'twin_clock'} - {self.namespace or '/'}
            if len(found) >= self.followers:
                return
            if not said:
                said = True
                self.node.get_logger().info(
                    f'waiting for {self.followers} twin(s) following /clock '
                    f'({len(found)} on the graph; at most {FOLLOWERS_WAIT_S:g} s)')
            if time.monotonic() - start > FOLLOWERS_WAIT_S:
                raise TwinError(
                    f'--followers {self.followers}: {len(found)} twin(s) following /clock '
                    f'came within {FOLLOWERS_WAIT_S:g} s ({", ".join(sorted(found)) or "none"}); '
                    'start each with --clock follow in a namespace of its own, in the same '
                    'ROS_DOMAIN_ID, or give fewer')
            time.sleep(PACE_SLICE_S)

    def _pace(self, due: float) -> None:
        """Wait until the wall clock reaches ``due``, in slices, so that a stop request is
        seen within one."""
        while not self.stopped():
            ahead = due - time.perf_counter()
            if ahead <= 0:
                return
            time.sleep(min(ahead, PACE_SLICE_S))

    def _wait_for_clock(self, t_ns: int) -> None:
        """Following: let the executor take what arrives -- the owner's /clock among it --
        until simulated time has reached ``t_ns``. Said once when the owner is slow to come;
        raises :class:`OwnerLeft` when an owner that was there leaves."""
        said = False
        checked = time.perf_counter()
        while self.owner_ns < t_ns and not self.stopped():
            self.executor.spin_once(timeout_sec=PACE_SLICE_S)
            now = time.perf_counter()
            if now - checked < OWNER_CHECK_S:
                continue
            checked = now
            owners = self.node.count_publishers('/clock')
            if owners == 0 and self.owner_ns >= 0:
                self.node.get_logger().warning(
                    f'the /clock owner left at {self.owner_ns * 1e-9:.3f} s of simulated '
                    'time: stopping here')
                raise OwnerLeft
            if not said:
                said = True
                self.node.get_logger().info(
                    f'waiting for /clock to reach {t_ns * 1e-9:.3f} s (this twin follows '
                    f'the clock owner; {owners} publisher(s) of /clock seen)')

    # -- callbacks ----------------------------------------------------------------------------
    def _on_clock(self, msg: Clock) -> None:
        t_ns = msg.clock.sec * 1_000_000_000 + msg.clock.nanosec
        if self.follow:
            self.owner_ns = max(self.owner_ns, t_ns)
        elif self._turn is not None and t_ns >= self.published_ns and not self._turn.done():
            self._turn.set_result(t_ns)

    def _on_turn(self, _msg: Empty) -> None:
        if self._turn is not None and not self._turn.done():
            self._turn.set_result(True)


class OwnerLeft(Exception):
    """The /clock owner a twin followed has left the graph."""


def absolute_namespace(namespace: str) -> str:
    """'left' or '/left' -> '/left', checked as ROS checks a namespace (one line otherwise)."""
    ns = '/' + namespace.strip('/')
    try:
        validate_namespace(ns)
    except InvalidNamespaceException as exc:
        raise TwinError(f'namespace {namespace!r}: {" ".join(str(exc).split())[:200]}; '
                        'expected names of letters, digits and _ separated by /') from None
    return ns


__all__ = ['EXECUTORS', 'GraphClock', 'OwnerLeft', 'absolute_namespace', 'CLOCK_QOS',
           'TICK_DEADLINE_S']
