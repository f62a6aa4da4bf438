"""What every storage shares: the :class:`Storage` interface, a topic's :class:`TopicInfo`,
and the QoS profiles of any rosbag2 version in the v9 names (:func:`normalise_qos`)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, Iterator

import yaml

from .. import safe_load

# rmw's enums, as rosbag2 versions <= 8 wrote them (rmw/types.h)
_HISTORY = {0: 'system_default', 1: 'keep_last', 2: 'keep_all', 3: 'unknown'}
_RELIABILITY = {0: 'system_default', 1: 'reliable', 2: 'best_effort', 3: 'unknown',
                4: 'best_available'}
_DURABILITY = {0: 'system_default', 1: 'transient_local', 2: 'volatile', 3: 'unknown',
               4: 'best_available'}
_LIVELINESS = {0: 'system_default', 1: 'automatic', 2: 'manual_by_node', 3: 'manual_by_topic',
               4: 'unknown', 5: 'best_available'}
_POLICIES = {'history': _HISTORY, 'reliability': _RELIABILITY, 'durability': _DURABILITY,
             'liveliness': _LIVELINESS}


def normalise_qos(raw: Any) -> list[dict[str, Any]]:
    """Offered QoS profiles as v9 stores them (a list of maps with policy names), from a v9
    list, a v4-8 YAML string, integer or name policies; [] when absent or unreadable."""
    if isinstance(raw, str):
        try:
            raw = safe_load(raw) if raw.strip() else []
        except yaml.YAMLError:
            return []
    if not isinstance(raw, list):
        return []
    out = []
    for prof in raw:
        if not isinstance(prof, dict):
            continue
        prof = dict(prof)
        for key, names in _POLICIES.items():
            v = prof.get(key)
            if isinstance(v, int) and not isinstance(v, bool):
                prof[key] = names.get(v, 'unknown')
            elif isinstance(v, str):
                prof[key] = v.lower()
        out.append(prof)
    return out


@dataclasses.dataclass
class TopicInfo:
    name: str
    type: str
    qos: list[dict[str, Any]]
    count: int = 0
    serialization_format: str = 'cdr'


# (topics, (first log time, last log time, message count)) of one file
Summary = tuple[dict[str, TopicInfo], tuple[int, int, int]]


class Storage:
    """One storage's reader of one file (the interface every registered storage fills)."""

    name: str = ''
    suffix: str = ''
    magic: bytes = b''

    def summary(self, f: Path) -> Summary:
        """Topics with counts and the time span; by default one pass over the messages."""
        topics: dict[str, TopicInfo] = {}
        t0 = t1 = None
        n = 0
        for topic, t, _ in self.messages(f, None, None, None, topics):
            topics[topic].count += 1
            t0 = t if t0 is None else min(t0, t)
            t1 = t if t1 is None else max(t1, t)
            n += 1
        return topics, (t0 or 0, t1 or 0, n)

    def messages(self, f: Path, keep: set[str] | None, start_ns: int | None,
                 end_ns: int | None, topics_out: dict[str, TopicInfo] | None = None
                 ) -> Iterator[tuple[str, int, bytes]]:
        """(topic, log time, CDR bytes) in log-time order; ``keep`` selects topics, the bounds
        are inclusive; ``topics_out`` collects each topic's description as it is met."""
        raise NotImplementedError

    def metadata(self, f: Path, *, checked: bool = False) -> dict[str, dict[str, str]]:
        """The file's named metadata records (name -> string map); none by default.
        ``checked``: the file's checksums were verified already (by :meth:`summary`)."""
        return {}


__all__ = ['Storage', 'TopicInfo', 'Summary', 'normalise_qos']
