"""The bag player: puts a recorded rosbag2 bag back on the ROS graph, modelled on
``ros2 bag play`` (rosbag2 is C++ and not on PyPI).

Every recorded message is published on its topic with its recorded type, in log-time order, as
the exact recorded CDR bytes (rclpy publishes serialized bytes as they are), with the recorded
reliability and durability where the bag has them (v9 names or the older integers) and
reliable/volatile otherwise. Pacing is wall time divided by ``rate``.

History: a bag records the *offered* QoS, whose history is ``unknown``. A reliable topic is
published keep-all: its samples stay in the player's history until every reliable subscriber
has acknowledged them, so the player never overwrites a message a subscriber has not
received -- at ``-r 1000`` a reliable subscriber in another process lost 14-23 % of the
messages to the keep-last-10 history this player had, even with a history of 20 000 of its own
-- and at the end of the bag it waits (up to :data:`ACK_WAIT_S`) until every reliable
subscriber has acknowledged everything, as ``ros2 bag play --wait-for-all-acked`` does.
The price is memory while a subscriber lags (a stopped one holds the samples until DDS gives up
on it; a message that cannot be queued is dropped, counted and named in a warning). A
subscriber that keeps the last N and *takes* them more slowly than they arrive still loses what
its own history overwrites, as with rosbag2: give it a history as deep as the burst it must
absorb. Best-effort topics are published keep-last 10 as recorded.

With ``clock`` > 0, ``/clock`` follows the bag time at that many messages per wall second (the
bag's own ``/clock`` is then not republished), so nodes with ``use_sim_time`` follow the bag.

Services (std_srvs/Trigger; rosbag2's names): ``~/pause``, ``~/resume``, ``~/toggle_paused``,
``~/play_next`` (publishes one message while paused; ``success`` false at the end of the bag),
``~/is_paused`` (``success`` is whether playback is paused).

Parameters (the ``ros2 bag play`` option names, fixed once playing; ``ros2 param get /player
rate`` reads them whether they came from ``-p`` or from :class:`PlayOptions`): ``bag``, ``rate``,
``clock`` (Hz, 0 = off), ``topics``, ``exclude_topics`` (string arrays), ``loop``, ``delay``,
``start_offset``, ``playback_duration`` (s; 0 = to the end), ``start_paused``, ``remap``
(``FROM:=TO`` strings). An integer given for a double is stored as the double.

rosbag2's player node offers its services with rosbag2_interfaces types (``Pause``, ``Resume``,
``TogglePaused``, ``IsPaused``, ``PlayNext``, ``GetRate``, ``SetRate``, ``Burst``, ``Seek``,
``Play``, ``Stop``). rosbag2_interfaces is a C++-built package that is not on PyPI, and a new
service type needs an ament_cmake build, so this player offers the five above under rosbag2's
names with std_srvs/Trigger; the rest are not offered.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from pathlib import Path
from typing import Sequence

from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy._rclpy_pybind11 import RCLError
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from std_srvs.srv import Trigger

from ..bag.anybag import AnyBag, open_any_bag
from ..errors import TwinError
from .clock import clock_msg
from .play_options import OPTION_DOCS, PlayOptions, absolute_topic, typed_option

_RELIABILITY = {'reliable': ReliabilityPolicy.RELIABLE,
                'best_effort': ReliabilityPolicy.BEST_EFFORT}
_DURABILITY = {'volatile': DurabilityPolicy.VOLATILE,
               'transient_local': DurabilityPolicy.TRANSIENT_LOCAL}


#: before playing, the player looks this long [wall s] for the subscribers already on the graph
#: (discovery takes tens of ms on one host) and waits until each is matched to its publisher,
#: at most MATCH_WAIT_S: without it the first 0.2 s of a bag at -r 1000 went out before a
#: subscriber that was there at start had matched (800 of 1001 messages, 1 run in 4)
DISCOVERY_S = 0.5
MATCH_WAIT_S = 5.0
#: how long the player waits at the end of the bag for its reliable subscribers to acknowledge
#: what it played before it goes [s]
ACK_WAIT_S = 30.0


def qos_for(recorded: list[dict]) -> QoSProfile:
    """The publisher QoS for a recorded topic (the first offered profile decides)."""
    prof = recorded[0] if recorded else {}
    reliability = _RELIABILITY.get(prof.get('reliability'), ReliabilityPolicy.RELIABLE)
    keep_all = prof.get('history') == 'keep_all' or reliability == ReliabilityPolicy.RELIABLE
    return QoSProfile(
        history=HistoryPolicy.KEEP_ALL if keep_all else HistoryPolicy.KEEP_LAST, depth=10,
        reliability=reliability,
        durability=_DURABILITY.get(prof.get('durability'), DurabilityPolicy.VOLATILE))


def message_class(type_name: str):
    """The installed message class of ``pkg/msg/Type``, or None. The name comes from a bag,
    which anyone may write: only a package that rosidl generated (it carries its
    ``<pkg>_s__rosidl_typesupport_c`` library) is imported, never an arbitrary module of that
    name (``this/msg/Foo`` would run ``this``'s import-time code)."""
    import importlib
    import importlib.util
    parts = type_name.split('/')
    if len(parts) != 3 or parts[1] not in ('msg', 'srv', 'action') or not all(
            p.isidentifier() for p in parts):
        return None
    try:
        # find_spec of a top-level name locates it without running it
        spec = importlib.util.find_spec(parts[0])
    except (ImportError, ValueError):
        return None
    dirs = list(spec.submodule_search_locations or []) if spec is not None else []
    if not any(any(Path(d).glob(f'{parts[0]}_s__rosidl_typesupport_c*')) for d in dirs):
        return None
    try:                       # what rosidl_runtime_py's get_message does (not on PyPI here)
        return getattr(importlib.import_module(f'{parts[0]}.{parts[1]}'), parts[2])
    except (ImportError, AttributeError, ValueError):
        return None


class Player(Node):
    """Plays ``bag`` with ``options`` (see the module docstring). Drive it with :meth:`run`
    (or :meth:`step` from your own loop); ``warnings`` lists the topics skipped."""

    def __init__(self, bag: AnyBag, options: PlayOptions, *, name: str = 'player', **kwargs):
        super().__init__(name, **kwargs)
        options.check()
        self.bag = bag
        self.options = options
        self._declare_options(bag, options)
        remaps = options.remaps()
        self.warnings: list[str] = []
        self.pubs = {}
        wanted = set(absolute_topic(t) for t in options.topics)
        unwanted = set(absolute_topic(t) for t in options.exclude_topics)
        # (a topic the bag lacks played nothing, rc 0: a typo looked like a quiet bag)
        missing = sorted(wanted - set(bag.topics))
        if missing:
            raise TwinError(f'topics {", ".join(missing)}: not in the bag, which has '
                            f'{", ".join(sorted(bag.topics))}')
        if options.start_offset * 1e9 >= bag.end_ns - bag.start_ns and bag.end_ns > bag.start_ns:
            raise TwinError(f'start_offset {options.start_offset:g} s lies at or past the '
                            f'bag\'s end ({(bag.end_ns - bag.start_ns) * 1e-9:g} s long)')
        for name_, info in sorted(bag.topics.items()):
            if wanted and name_ not in wanted or name_ in unwanted:
                continue
            if options.clock > 0 and name_ == '/clock':
                continue                      # our /clock replaces the recorded one
            if info.serialization_format not in ('cdr', ''):
                self.warnings.append(f'skipping {name_}: serialization '
                                     f'{info.serialization_format!r} is not CDR')
                continue
            cls = message_class(info.type)
            if cls is None:
                self.warnings.append(f'skipping {name_}: message type {info.type!r} is not '
                                     'installed')
                continue
            target = remaps.get(name_, name_)
            try:
                self.pubs[name_] = self.create_publisher(cls, target, qos_for(info.qos))
            except RCLError as exc:   # e.g. a remap onto a topic of another type
                raise TwinError(f'cannot publish {name_} ({info.type}) as {target}: '
                                f'{" ".join(str(exc).split(", at ")[0].split())[:200]}'
                                ) from None
        self.clock_pub = (self.create_publisher(Clock, '/clock', 10)
                          if options.clock > 0 else None)
        self.dropped = 0
        self._said_dropped: set[str] = set()
        self.paused = options.start_paused
        self.published = 0
        #: live consumers of every played message (topic, CDR bytes, log time): Foxglove
        self.sinks: list = []
        self._play_next = 0
        for srv, fn in (('pause', self._srv_pause), ('resume', self._srv_resume),
                        ('toggle_paused', self._srv_toggle), ('play_next', self._srv_next),
                        ('is_paused', self._srv_is_paused)):
            self.create_service(Trigger, f'~/{srv}', fn)
        self._stream = None
        self._pending = None                  # (topic, t, data) taken from the stream
        self._finished = False
        t0 = bag.start_ns + int(round(options.start_offset * 1e9))
        self._first_ns = t0
        self._last_ns = (bag.end_ns if options.playback_duration == 0
                         else t0 + int(round(options.playback_duration * 1e9)))
        self.bag_now_ns = t0
        self._restart()

    def wait_for_subscribers(self, executor, stop=None) -> None:
        """Block (spinning ``executor``) until the subscribers are there: with
        ``wait_for_subscribers`` N, until every played topic has N matched subscribers (as long
        as it takes; one line says what it waits for after a second); with 0, until every
        subscriber the graph shows on a played topic after :data:`DISCOVERY_S` is matched, at
        most :data:`MATCH_WAIT_S`. Playback is paced from the end of the wait."""
        n = self.options.wait_for_subscribers
        t0 = time.monotonic()
        said = False
        while self.pubs and not (stop and stop()):
            waited = time.monotonic() - t0
            matched = {t: p.get_subscription_count() for t, p in self.pubs.items()}
            if n:
                short = sorted(t for t, c in matched.items() if c < n)
                if not short:
                    break
                if not said and waited > 1.0:
                    said = True
                    print(f'play: waiting for {n} subscriber(s) on {", ".join(short[:3])}'
                          + (' ...' if len(short) > 3 else ''), file=sys.stderr, flush=True)
            elif waited >= DISCOVERY_S:
                seen = {t: self.count_subscribers(p.topic_name) for t, p in self.pubs.items()}
                if all(matched[t] >= seen[t] for t in self.pubs):
                    break
                if waited >= MATCH_WAIT_S:
                    late = sorted(t for t in self.pubs if matched[t] < seen[t])
                    self.warnings.append(f'played after {MATCH_WAIT_S:g} s with subscribers '
                                         f'not yet matched (incompatible QoS?) on {late[:3]}')
                    break
            executor.spin_once(timeout_sec=0.02)
        self._anchor(self._first_ns, delay=self.options.delay)

    def _declare_options(self, bag: AnyBag, options: PlayOptions) -> None:
        """The options as the node's parameters, with the values in force (a ``-p`` override
        was read into ``options`` already, converted; it is not applied again)."""
        values = {'bag': str(bag.path), **dataclasses.asdict(options)}
        for name, value in values.items():
            desc = ParameterDescriptor(description=OPTION_DOCS[name])
            if isinstance(value, tuple):
                # rclpy types an empty list as a byte array: declare the type, then the value
                self.declare_parameter(name, Parameter.Type.STRING_ARRAY, desc,
                                       ignore_override=True)
                self.set_parameters([Parameter(name, Parameter.Type.STRING_ARRAY,
                                               list(value))])
            else:
                desc.read_only = True
                self.declare_parameter(name, value, desc, ignore_override=True)
        self.add_on_set_parameters_callback(self._refuse_option_changes)

    def _refuse_option_changes(self, params: list[Parameter]) -> SetParametersResult:
        fixed = [p.name for p in params if p.name in OPTION_DOCS]
        if fixed:
            return SetParametersResult(
                successful=False, reason=f'{fixed[0]} is fixed while playing: start the '
                'player again with the new value')
        return SetParametersResult(successful=True)

    # -- services -------------------------------------------------------------------------
    def _srv_pause(self, _req, resp):
        self._set_paused(True)
        resp.success, resp.message = True, 'paused'
        return resp

    def _srv_resume(self, _req, resp):
        self._set_paused(False)
        resp.success, resp.message = True, 'playing'
        return resp

    def _srv_toggle(self, _req, resp):
        self._set_paused(not self.paused)
        resp.success, resp.message = True, 'paused' if self.paused else 'playing'
        return resp

    def _srv_next(self, _req, resp):
        if not self.paused:
            resp.success, resp.message = False, 'play_next works while paused'
            return resp
        ok = self._publish_next()
        resp.success = ok
        resp.message = 'published one message' if ok else 'end of the bag'
        return resp

    def _srv_is_paused(self, _req, resp):
        resp.success, resp.message = self.paused, 'paused' if self.paused else 'playing'
        return resp

    def _set_paused(self, paused: bool) -> None:
        if paused == self.paused:
            return
        self.paused = paused
        if not paused:                         # the wall clock resumes from the bag time
            self._anchor(self.bag_now_ns)

    # -- playback -------------------------------------------------------------------------
    def _restart(self) -> None:
        self._stream = self.bag.messages(topics=list(self.pubs), start_ns=self._first_ns,
                                         end_ns=self._last_ns)
        self._pending = next(self._stream, None)
        self.bag_now_ns = self._first_ns
        self._anchor(self._first_ns, delay=self.options.delay)

    def _anchor(self, bag_ns: int, delay: float = 0.0) -> None:
        self._wall0 = time.monotonic() + delay
        self._bag0 = bag_ns

    def _due_wall(self, bag_ns: int) -> float:
        return self._wall0 + (bag_ns - self._bag0) * 1e-9 / self.options.rate

    def _publish_next(self) -> bool:
        if self._pending is None:
            return False
        topic, t, data = self._pending
        try:
            self.pubs[topic].publish(data)
        except RCLError as exc:
            # a keep-all history full of what a subscriber never acknowledged (a stopped
            # process, before DDS gives up on it): the message is dropped, once said
            self.dropped += 1
            if topic not in self._said_dropped:
                self._said_dropped.add(topic)
                self.warnings.append(f'{topic}: a message could not be delivered (a '
                                     'subscriber acknowledges nothing?): '
                                     f'{" ".join(str(exc).split(", at ")[0].split())[:160]}')
        for sink in self.sinks:
            sink(topic, data, t)
        self.published += 1
        self.bag_now_ns = t
        self._pending = next(self._stream, None)
        return True

    def step(self, max_wait: float = 0.05) -> float:
        """Publish what is due now; returns how long (wall s, at most ``max_wait``) until the
        next message is due. Sets ``finished`` at the end (after the last loop)."""
        if self._finished:
            return max_wait
        if self.paused:
            return max_wait
        now = time.monotonic()
        while self._pending is not None and self._due_wall(self._pending[1]) <= now:
            self._publish_next()
        if self._pending is None:
            if self.options.loop:
                self._restart()
                return 0.0
            self.bag_now_ns = self._last_ns
            self._finished = True
            return 0.0
        # bag time advances with the wall clock between messages (for /clock)
        self.bag_now_ns = max(self.bag_now_ns, min(
            self._pending[1], self._bag0 + int((now - self._wall0) * self.options.rate * 1e9)))
        return max(0.0, min(max_wait, self._due_wall(self._pending[1]) - now))

    @property
    def finished(self) -> bool:
        return self._finished

    def wait_for_acknowledgements(self, timeout_s: float = ACK_WAIT_S) -> bool:
        """Wait until every reliable subscriber has acknowledged every message played (what
        ``ros2 bag play --wait-for-all-acked`` does): the messages still queued when a player
        is destroyed are lost -- under load a subscriber received 101 of 1001 at ``-r 1000``.
        False, with a warning, if one has not within ``timeout_s`` (e.g. a stopped process)."""
        deadline = time.monotonic() + timeout_s
        for topic, pub in self.pubs.items():
            if pub.qos_profile.reliability != ReliabilityPolicy.RELIABLE:
                continue
            left = max(0.0, deadline - time.monotonic())
            if not pub.wait_for_all_acked(Duration(nanoseconds=int(left * 1e9))):
                self.warnings.append(f'{topic}: not every subscriber acknowledged the last '
                                     f'messages within {timeout_s:g} s')
                return False
        return True

    def publish_clock(self) -> None:
        if self.clock_pub is not None:
            self.clock_pub.publish(clock_msg(self.bag_now_ns))


def play(bag_path, options: PlayOptions, *, context=None, progress: bool | None = None,
         stop=None, on_ready=None, foxglove: int | None = None) -> dict:
    """Play a bag to the end (or until ``stop()`` is true); returns counts and wall time.

    ``progress``: a single updating line on stderr (default: when stderr is a terminal);
    ``foxglove``: also serve the played messages to the Foxglove app on this localhost port."""
    from rclpy.executors import SingleThreadedExecutor
    bag = open_any_bag(bag_path)
    player = Player(bag, options, context=context)
    for w in player.warnings:
        print(f'play: warning: {w}', file=sys.stderr)
    n_warnings = len(player.warnings)
    live = None
    if foxglove is not None:
        from .live import FoxgloveLive
        # block: the viewer gets every message, as a reliable subscriber does
        live = FoxgloveLive({t: bag.topics[t].type for t in player.pubs}, port=foxglove,
                            block=True)
        player.sinks.append(live.log)
    ex = SingleThreadedExecutor(context=context)
    ex.add_node(player)
    show = sys.stderr.isatty() if progress is None else progress
    period = 1.0 / options.clock if options.clock > 0 else None
    next_clock = 0.0
    next_line = 0.0
    player.wait_for_subscribers(ex, stop)
    wall0 = time.monotonic()
    if on_ready is not None:
        on_ready(player)
    try:
        player.publish_clock()
        while not player.finished and not (stop and stop()):
            wait = player.step()
            now = time.monotonic()
            if period is not None and now >= next_clock:
                player.publish_clock()
                next_clock = now + period
                wait = min(wait, period)
            if show and now >= next_line:
                rate = player.published / max(now - wall0, 1e-9)
                print(f'\r[play] bag time {(player.bag_now_ns - bag.start_ns) * 1e-9:9.3f} s '
                      f'| {player.published} messages | {rate:8.0f} msg/s'
                      + (' | paused' if player.paused else '        '), end='',
                      file=sys.stderr, flush=True)
                next_line = now + 0.2
            ex.spin_once(timeout_sec=wait)
        player.publish_clock()
        if player.finished:
            player.wait_for_acknowledgements()
    finally:
        if show:
            print(file=sys.stderr)
        for w in player.warnings[n_warnings:]:      # met while playing
            print(f'play: warning: {w}', file=sys.stderr)
        ex.shutdown()
        if live is not None:
            live.close()
        published = player.published
        player.destroy_node()
    return dict(published=published, wall_s=time.monotonic() - wall0,
                bag_duration_s=bag.duration_ns * 1e-9, warnings=player.warnings)


def main(args: Sequence[str] | None = None) -> int:
    """``ros2 run servovalve_twin player --ros-args -p bag:=DIR [-p rate:=2.0] [-p clock:=40.0]
    [-p topics:="['/xj']"] [-p loop:=true] ...``."""
    from .process import ros_main
    from .rosargs import ros_parameters
    usage = ('usage: player --ros-args -p bag:=DIR [-p rate:=F] [-p clock:=HZ] '
             '[-p topics:=[...]] [-p exclude_topics:=[...]] [-p loop:=true] [-p delay:=S] '
             '[-p start_offset:=S] [-p playback_duration:=S] [-p start_paused:=true] '
             '[-p remap:=[FROM:=TO]] [-p wait_for_subscribers:=N]\n'
             'example: ros2 run servovalve_twin player --ros-args -p bag:=bags/hd -p rate:=4.0')

    def body(context, stopped) -> int:
        fields = [f.name for f in dataclasses.fields(PlayOptions)]
        values = ros_parameters(context, 'player', ['bag'] + fields)
        if not values.get('bag'):
            raise TwinError('give the bag to play: --ros-args -p bag:=DIR')
        opts = {f.name: typed_option(f.name, values[f.name], f.default)
                for f in dataclasses.fields(PlayOptions) if f.name in values}
        result = play(values['bag'], PlayOptions(**opts), context=context, stop=stopped,
                      on_ready=lambda player: print(f'player: playing {values["bag"]}',
                                                    flush=True))
        print(f'player: {result["published"]} messages in {result["wall_s"]:.2f} s')
        return 0
    return ros_main('player', body, args, usage)
