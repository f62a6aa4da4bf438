"""A run read back from a bag as the twin's 1 ms signal table (:func:`read_bag`): a thin table
builder on the one bag reader, :func:`~.anybag.open_any_bag`, so it reads every storage and
layout that reader reads (rebuilding a bag cut short is :mod:`.reindex`).

Every failure -- missing file, truncated or corrupt storage, a bag of another layout, a
malformed provenance record -- is a :class:`~servovalve_twin.errors.BagError` with a one-line
reason, never a traceback.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import BagError
from ..physics.simulate import CSV_COLUMNS
from .anybag import AnyBag, open_any_bag
from .cdr import decode_float64
from .provenance import Provenance
from .table import signal_table

FLOAT64 = 'std_msgs/msg/Float64'


@dataclasses.dataclass
class BagRun:
    """A run read back from a bag: the 1 ms rows of its Float64 topics and its provenance."""

    path: Path
    signals: dict[str, np.ndarray]
    topics: dict[str, int]                  # topic -> message count
    provenance: Provenance
    series: dict[str, tuple[np.ndarray, np.ndarray]]   # topic -> (log time ns, value), every tick

    @property
    def valve_model(self) -> str | None:
        return self.provenance.valve_model

    def params(self) -> dict[str, Any]:
        return dict(self.provenance.params)

    def scenario(self) -> dict[str, Any] | None:
        return self.provenance.scenario

    @property
    def control_period(self) -> float | None:
        return self.provenance.control_period


def check_signal_types(bag: AnyBag) -> None:
    """Refuse a bag in which a topic named as one of the twin's signals (under its namespace)
    has another type than std_msgs/Float64: read by type, such a topic was left out without a
    word (an altered sqlite3 bag's /xj made `compare` drop XJ and compare the rest)."""
    ns = bag.provenance.namespace or ''
    for name, info in bag.topics.items():
        own = name[len(ns):] if ns and name.startswith(ns + '/') else name
        if own[1:] in CSV_COLUMNS[1:] and info.type != FLOAT64:
            raise BagError(f'bag {str(bag.path)!r}: topic {name} has type {info.type!r}; the '
                           f"twin's signals are {FLOAT64} (the bag was altered?)")


def float64_series(bag: AnyBag, topics=None, counts: dict[str, int] | None = None
                   ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """``{topic: (log times ns, values)}`` of the bag's std_msgs/Float64 topics (or of
    ``topics`` among them), each in log-time order. ``counts``: read every topic, and count
    each one's messages into it."""
    check_signal_types(bag)
    f64 = set(bag.topics_of_type(FLOAT64))
    if topics is not None:
        f64 &= set(topics)
    # arrays sized by the bag's own counts, filled in place: 16 bytes a message, where lists
    # of Python ints and floats took ~90 (a 100 s run's million messages: 94 -> 16 MB)
    series = {t: _Series(bag.topics[t].count) for t in f64}
    for topic, t_ns, data in bag.messages(topics=None if counts is not None else f64):
        if counts is not None:
            counts[topic] = counts.get(topic, 0) + 1
        s = series.get(topic)
        if s is not None:
            s.append(t_ns, _value(bag.path, topic, t_ns, data))
    out = {k: s.arrays() for k, s in series.items() if s.n}
    period = bag.provenance.control_period
    if period:
        check_ticks(bag.path, out, int(round(period * 1e9)), bag.storage)
    return out


def _value(path: Path, topic: str, t_ns: int, data: bytes) -> float:
    """A Float64 message's value; CDR that does not decode is a corrupt bag."""
    try:
        return decode_float64(data)
    except ValueError as exc:
        raise BagError(f'bag {str(path)!r} is corrupt: its message on {topic} at '
                       f'{t_ns * 1e-9:.6f} s: {exc}') from None


class _Series:
    """One topic's (log time, value) pairs in arrays grown by doubling from the expected
    count (exact when the bag's summary is right; a summary that undercounts still reads,
    and read_bag then refuses the disagreement)."""

    def __init__(self, expected: int):
        size = max(int(expected), 16)
        self.t = np.empty(size, dtype=np.int64)
        self.v = np.empty(size)
        self.n = 0

    def append(self, t_ns: int, value: float) -> None:
        if self.n == self.t.size:
            self.t = np.resize(self.t, 2 * self.n)
            self.v = np.resize(self.v, 2 * self.n)
        self.t[self.n] = t_ns
        self.v[self.n] = value
        self.n += 1

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        if self.n == self.t.size:               # the summary's count: no copy
            return self.t, self.v
        return self.t[:self.n].copy(), self.v[:self.n].copy()


#: the signals the plant publishes at every tick (not the port pressures: see check_ticks)
_EVERY_TICK = frozenset(CSV_COLUMNS[1:])


def check_ticks(path: Path, series: dict[str, tuple[np.ndarray, np.ndarray]], period_ns: int,
                storage: str = 'mcap') -> None:
    """The twin publishes its Float64 topics at control-period ticks, the plant's signals at
    every one (the port pressures only while a model with ports is in force; an algorithm's
    outputs at its own ticks): a message off that grid, twice at one tick or, for a signal,
    missing between two is a damaged bag -- sqlite3 keeps no checksum, so a flipped byte in a
    timestamp would otherwise drop a tick from every table silently."""
    for topic, (t, _) in series.items():
        if not t.size:
            continue
        step = np.diff(t)
        gaps_allowed = topic.rsplit('/', 1)[-1] not in _EVERY_TICK
        bad = np.nonzero((step <= 0) | (step % period_ns != 0) | (
            (step != period_ns) & (not gaps_allowed)))[0]
        off = t[0] % period_ns != 0
        if off or bad.size:
            at = t[0] if off else t[bad[0] + 1]
            # (an MCAP file's checksums held: its messages are as written, so the record
            # that states the period is the one to doubt -- not sqlite3, which was blamed)
            why = ('a damaged or edited file; sqlite3 keeps no checksum' if storage == 'sqlite3'
                   else 'its checksums hold: an edited provenance record, or a recorder that '
                        'is not the twin')
            raise BagError(f'bag {str(path)!r} is corrupt: {topic} is not one message per '
                           f'control period ({period_ns * 1e-6:g} ms) at {at * 1e-9:.6f} s '
                           f'({why})')


def read_bag(path: str | Path, *, require_metadata: bool = True) -> BagRun:
    """Read a bag written by the twin (or any bag with Float64 topics of the same names)."""
    p = Path(path)
    bag = open_any_bag(p, require_metadata=require_metadata)
    counts: dict[str, int] = {}
    arrays = float64_series(bag, counts=counts)
    if not arrays:
        raise BagError(f'bag {str(p)!r} holds no std_msgs/Float64 topics of the twin')
    _check_counts(p, bag, counts)
    ns = bag.provenance.namespace
    if ns:      # a namespaced actuator's topics ('/left/xj') are the twin's signals
        arrays = {t[len(ns):]: v for t, v in arrays.items() if t.startswith(ns + '/')}
        if not arrays:
            raise BagError(f'bag {str(p)!r} holds no std_msgs/Float64 topics under its '
                           f'namespace {ns}')
    return BagRun(path=p, signals=signal_table(arrays), topics=counts,
                  provenance=bag.provenance, series=arrays)


#: Float64 messages held at most between two blocks of :func:`iter_signal_blocks` (~5 MB)
BLOCK_MESSAGES = 1 << 16


def iter_float64_blocks(bag: AnyBag, topics=None, *, counts: dict[str, int] | None = None,
                        block_messages: int | None = None):
    """:func:`float64_series` in consecutive blocks, in memory that does not grow with the bag:
    yields ``{topic: (log times ns, values)}`` of every Float64 topic (or of ``topics`` among
    them; arrays empty where a block has none) holding every message logged before the time
    of the one that filled the block -- all messages of one log time fall in one block
    (log-time order). The tick check runs across blocks. ``counts``: read every topic and
    count each one's messages into it."""
    import bisect
    block_messages = block_messages or BLOCK_MESSAGES
    p = bag.path
    check_signal_types(bag)
    f64 = set(bag.topics_of_type(FLOAT64))
    if topics is not None:
        f64 &= set(topics)
    period = bag.provenance.control_period
    period_ns = int(round(period * 1e9)) if period else None
    buf = {t: ([], []) for t in f64}
    carry: dict[str, int] = {}

    def emit(cut):
        series = {}
        for topic, (ts, vs) in buf.items():
            k = len(ts) if cut is None else bisect.bisect_left(ts, cut)
            t = np.array(ts[:k], dtype=np.int64)
            v = np.array(vs[:k], dtype=float)
            del ts[:k], vs[:k]
            if period_ns and k:
                # the tick check across blocks: the previous block's last tick leads this one
                head = [carry[topic]] if topic in carry else []
                check_ticks(p, {topic: (np.concatenate([head, t]).astype(np.int64), None)},
                            period_ns, bag.storage)
            if k:
                carry[topic] = int(t[-1])
            series[topic] = (t, v)          # every topic, empty ones too (a table's columns)
        return series if any(t.size for t, _ in series.values()) else None

    held = 0
    for topic, t_ns, data in bag.messages(topics=None if counts is not None else f64):
        if counts is not None:
            counts[topic] = counts.get(topic, 0) + 1
        b = buf.get(topic)
        if b is None:
            continue
        b[0].append(t_ns)
        b[1].append(_value(p, topic, t_ns, data))
        held += 1
        if held >= block_messages:
            series = emit(t_ns)
            held = sum(len(ts) for ts, _ in buf.values())
            if series is not None:
                yield series
    series = emit(None)
    if series is not None:
        yield series


def iter_signal_blocks(path: str | Path, *, block_messages: int | None = None,
                       require_metadata: bool = True):
    """:func:`read_bag`'s 1 ms signal table in consecutive blocks of rows, read in memory that
    does not grow with the bag: the same rows, the same checks (ticks on the control-period
    grid, every-tick signals without a gap, the summary's counts -- after the last block).
    Yields ``(bag, rows)``; ``rows`` holds every column the bag has, NaN-padded port
    pressures included. A block ends at the log time of the message that filled it: every
    message before that time has been read (log-time order), so its rows are complete."""
    p = Path(path)
    bag = open_any_bag(p, require_metadata=require_metadata)
    # (a topic the summary counts no message on is none: the count is checked at the end)
    f64 = {t for t in bag.topics_of_type(FLOAT64) if bag.topics[t].count}
    ns = bag.provenance.namespace
    mine = {t: t[len(ns):] if ns else t for t in f64 if not ns or t.startswith(ns + '/')}
    if not any(name[1:] in CSV_COLUMNS[1:] for name in mine.values()):
        raise BagError(f'bag {str(p)!r} holds no std_msgs/Float64 topics of the twin'
                       + (f' under its namespace {ns}' if ns else ''))
    counts: dict[str, int] = {}
    for series in iter_float64_blocks(bag, f64, counts=counts, block_messages=block_messages):
        rows = signal_table({mine[t]: tv for t, tv in series.items() if t in mine})
        if rows['t'].size:
            yield bag, rows
    _check_counts(p, bag, counts)


def read_bag_until(path: str | Path, t_end: float | None) -> BagRun:
    """:func:`read_bag`'s signal table holding only the rows up to ``t_end`` [s] (all when
    None); the rest of the bag is still read and checked, block by block
    (:func:`iter_signal_blocks`), in memory that does not grow with it. ``topics`` and
    ``series`` stay empty (what a windowed diagnosis does not use)."""
    if t_end is None:
        return read_bag(path)
    kept, bag = [], None
    for bag, rows in iter_signal_blocks(path):
        if rows['t'][0] <= t_end + 5e-4:            # (rows lie on whole milliseconds)
            keep = rows['t'] <= t_end + 5e-4
            kept.append({k: v[keep] for k, v in rows.items()})
    if not kept:
        raise BagError(f'bag {str(path)!r} holds no row of the twin\'s signals')
    return BagRun(path=Path(path), signals={k: np.concatenate([b[k] for b in kept])
                                            for k in kept[0]},
                  topics={}, provenance=bag.provenance, series={})


def _check_counts(p: Path, bag: AnyBag, counts: dict[str, int]) -> None:
    """The summary's counts are a claim (MCAP statistics carry no CRC of their own here):
    what was read must agree with it."""
    claimed = {name: info.count for name, info in bag.topics.items() if info.count}
    if claimed != counts:
        bad = sorted(t for t in set(claimed) | set(counts) if claimed.get(t) != counts.get(t))
        raise BagError(f'bag {str(p)!r} is corrupt: its summary counts {claimed.get(bad[0], 0)} '
                       f'messages on {bad[0]} but it holds {counts.get(bad[0], 0)}; try: '
                       f'servovalve-twin reindex {p}')


def mcap_path(path: str | Path) -> Path:
    """The one ``.mcap`` file of a bag directory (or the file given): what :mod:`.reindex`
    rebuilds, which needs MCAP's records."""
    p = Path(path)
    if p.is_file():
        return p
    if not p.is_dir():
        raise BagError(f'no bag at {str(p)!r}: not a directory or .mcap file')
    files = sorted(p.glob('*.mcap'))
    if not files:
        raise BagError(f'bag directory {str(p)!r} holds no .mcap file (reindex rebuilds MCAP '
                       'bags; a sqlite3 bag has no summary to rebuild)')
    if len(files) > 1:
        raise BagError(f'bag directory {str(p)!r} holds {len(files)} .mcap files; reindex '
                       'rebuilds one file at a time: give it the .mcap file')
    return files[0]


__all__ = ['BagRun', 'read_bag', 'read_bag_until', 'iter_signal_blocks', 'float64_series',
           'mcap_path', 'FLOAT64']
