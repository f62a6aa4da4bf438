"""The player's options: what ``ros2 bag play`` takes, with its option names (:class:`PlayOptions`),
their bounds, their documentation as the player node's parameters, and the reading of a
``-p`` value as an option's type."""

from __future__ import annotations

import dataclasses
from typing import Any

from ..errors import TwinError


def absolute_topic(topic: str) -> str:
    return topic if topic.startswith('/') else '/' + topic


@dataclasses.dataclass
class PlayOptions:
    """What ``ros2 bag play`` takes, with its option names."""

    rate: float = 1.0
    clock: float = 0.0                  # Hz of /clock from the bag time; 0 = off
    topics: tuple[str, ...] = ()
    exclude_topics: tuple[str, ...] = ()
    loop: bool = False
    delay: float = 0.0
    start_offset: float = 0.0
    playback_duration: float = 0.0      # 0 = to the end
    start_paused: bool = False
    remap: tuple[str, ...] = ()         # FROM:=TO
    wait_for_subscribers: int = 0       # play once every topic has this many (0: see below)

    def check(self) -> None:
        lo, hi = RATE_RANGE
        if not lo <= self.rate <= hi:
            # a rate of 1e-300 was accepted and played 13 messages in 8 s, never ending
            raise TwinError(f'rate must be a factor in [{lo:g}, {hi:g}], got {self.rate!r}')
        if not 0 <= self.clock <= MAX_CLOCK_HZ:
            raise TwinError(f'clock must be in [0, {MAX_CLOCK_HZ:g}] Hz (0 = no /clock), got '
                            f'{self.clock!r}')
        for name in ('delay', 'start_offset', 'playback_duration'):
            v = getattr(self, name)
            if not 0 <= v <= MAX_SECONDS:
                raise TwinError(f'{name} must be in [0, {MAX_SECONDS:g}] s, got {v!r}')
        n = self.wait_for_subscribers
        if isinstance(n, bool) or not isinstance(n, int) or not 0 <= n <= MAX_SUBSCRIBERS:
            raise TwinError(f'wait_for_subscribers must be a whole number in [0, '
                            f'{MAX_SUBSCRIBERS}], got {n!r}')
        targets = self.remaps().values()
        if '/clock' in targets:
            raise TwinError('a remap onto /clock is not allowed: /clock carries simulated time '
                            '(rosgraph_msgs/Clock; the player publishes it with --clock)')

    def remaps(self) -> dict[str, str]:
        out = {}
        for item in self.remap:
            a, sep, b = item.partition(':=')
            if not sep or not a or not b:
                raise TwinError(f'remap expects FROM:=TO, got {item!r}')
            out[absolute_topic(a)] = absolute_topic(b)
        return out


#: the playback rates allowed: slower than 1/1000 never ends a bag of seconds in a day
RATE_RANGE = (1e-3, 1e6)
#: the longest delay, offset or playback duration [s] (about 11.6 days)
MAX_SECONDS = 1e6
#: the fastest /clock [Hz]
MAX_CLOCK_HZ = 1e4
#: the most subscribers a player may be told to wait for
MAX_SUBSCRIBERS = 1000

#: the player's parameters: rosbag2's ``ros2 bag play`` options
OPTION_DOCS = {
    'bag': 'the bag played (directory or file)',
    'rate': 'playback rate: bag seconds per wall second',
    'clock': 'publish /clock from the bag time at this many Hz (0: off)',
    'topics': 'only these topics (empty: every topic)',
    'exclude_topics': 'not these topics',
    'loop': 'play again from the start at the end',
    'delay': 'wall seconds to wait before playing',
    'start_offset': 'start this many seconds into the bag',
    'playback_duration': 'play this many bag seconds (0: to the end)',
    'start_paused': 'start paused (resume with ~/resume)',
    'remap': 'FROM:=TO topic remappings',
    'wait_for_subscribers': 'play once every played topic has this many matched subscribers '
                            '(0: once those already on the graph are matched, at most 5 s)',
}


def typed_option(name: str, value: Any, default: Any) -> Any:
    """A ``-p`` value as the option's type (that of its default), or one error line: rcl
    hands over whatever YAML made of the text (``-p rate:=fast`` is the string 'fast')."""
    if isinstance(default, tuple):
        if isinstance(value, (list, tuple)) and all(isinstance(v, str) for v in value):
            return tuple(value)
        raise TwinError(f'{name} = {value!r}: expected a list of strings, e.g. "[\'/xj\']"')
    if isinstance(default, bool):
        if isinstance(value, bool):
            return value
        raise TwinError(f'{name} = {value!r}: expected true or false')
    if isinstance(default, int) and isinstance(value, int) and not isinstance(value, bool):
        return value
    if isinstance(default, float) and isinstance(value, (int, float)) and not isinstance(
            value, bool):
        return float(value)
    raise TwinError(f'{name} = {value!r}: expected a number')
