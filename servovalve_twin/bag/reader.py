"""Reading the twin's bags back, and rebuilding a bag cut short (``reindex``).

A bag is a directory holding ``<name>_0.mcap`` and ``metadata.yaml`` (or the ``.mcap`` file
itself). Every failure -- missing file, truncated or corrupt MCAP, a bag of another layout --
is a :class:`~servovalve_twin.errors.BagError` with a one-line reason, never a traceback.
"""

from __future__ import annotations

import dataclasses
import shutil
import struct
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import yaml

from ..errors import BagError
from .cdr import decode_float64
from .writer import BagWriter

PROVENANCE = 'servovalve_twin'
_CORRUPT = (EOFError, struct.error, ValueError, KeyError, IndexError, UnicodeDecodeError,
            MemoryError, OverflowError)


def _mcap_errors() -> tuple[type[BaseException], ...]:
    from mcap.exceptions import McapError
    return (McapError,) + _CORRUPT


def mcap_path(path: str | Path) -> Path:
    """The ``.mcap`` file of a bag directory (or the file given)."""
    p = Path(path)
    if p.is_file():
        return p
    if not p.is_dir():
        raise BagError(f'no bag at {str(p)!r}: not a directory or .mcap file')
    files = sorted(p.glob('*.mcap'))
    if not files:
        raise BagError(f'bag directory {str(p)!r} holds no .mcap file')
    if len(files) > 1:
        raise BagError(f'bag directory {str(p)!r} holds {len(files)} .mcap files; split bags '
                       'are not supported')
    return files[0]


@dataclasses.dataclass
class BagRun:
    """A run read back from a bag: the 1 ms rows of its Float64 topics and its provenance."""

    path: Path
    signals: dict[str, np.ndarray]
    topics: dict[str, int]                  # topic -> message count
    provenance: dict[str, str]
    series: dict[str, tuple[np.ndarray, np.ndarray]]   # topic -> (log time ns, value), every tick

    @property
    def valve_model(self) -> str | None:
        return self.provenance.get('valve_model')

    def params(self) -> dict[str, Any]:
        text = self.provenance.get('params')
        return yaml.safe_load(text) if text else {}

    def scenario(self) -> dict[str, Any] | None:
        text = self.provenance.get('scenario')
        return yaml.safe_load(text) if text else None

    @property
    def control_period(self) -> float | None:
        cp = self.provenance.get('control_period')
        return float(cp) if cp else None


def read_bag(path: str | Path, *, require_metadata: bool = True) -> BagRun:
    """Read a bag written by the twin (or any bag with Float64 topics of the same names)."""
    from mcap.reader import make_reader
    p = Path(path)
    if p.is_dir() and require_metadata and not (p / 'metadata.yaml').is_file():
        raise BagError(f'bag {str(p)!r} has no metadata.yaml (an interrupted run?); rebuild it '
                       f'with: servovalve-twin reindex {p}')
    file = mcap_path(p)
    series: dict[str, tuple[list[int], list[float]]] = {}
    counts: dict[str, int] = {}
    provenance: dict[str, str] = {}
    try:
        with open(file, 'rb') as fh:
            reader = make_reader(fh)
            for schema, channel, message in reader.iter_messages(log_time_order=True):
                counts[channel.topic] = counts.get(channel.topic, 0) + 1
                if schema is not None and schema.name == 'std_msgs/msg/Float64':
                    t, v = series.setdefault(channel.topic, ([], []))
                    t.append(message.log_time)
                    v.append(decode_float64(message.data))
            for meta in reader.iter_metadata():
                if meta.name == PROVENANCE:
                    provenance = dict(meta.metadata)
    except OSError as exc:
        raise BagError(f'cannot read bag {str(file)!r}: {exc.strerror}') from None
    except _mcap_errors() as exc:
        raise BagError(f'bag {str(file)!r} is truncated or corrupt ({type(exc).__name__}: '
                       f'{str(exc)[:120]}); try: servovalve-twin reindex {p}') from None
    if not series:
        raise BagError(f'bag {str(file)!r} holds no std_msgs/Float64 topics of the twin')
    arrays = {k: (np.array(t, dtype=np.int64), np.array(v)) for k, (t, v) in series.items()}
    return BagRun(path=p, signals=_rows(arrays), topics=counts, provenance=provenance,
                  series=arrays)


def _rows(series: dict[str, tuple[np.ndarray, np.ndarray]]) -> dict[str, np.ndarray]:
    """The 1 ms rows (t, com, fr, ...) of the twin's CSV from the per-tick series."""
    from ..physics.simulate import CSV_COLUMNS, OUTPUT_PERIOD_NS, PORT_COLUMNS
    cols = {}
    for col in CSV_COLUMNS[1:] + PORT_COLUMNS:
        if f'/{col}' not in series:
            continue
        t, v = series[f'/{col}']
        on_grid = t % OUTPUT_PERIOD_NS == 0
        cols[col] = (t[on_grid] // OUTPUT_PERIOD_NS, v[on_grid])
    if not cols:
        raise BagError('the bag holds none of the twin topics ' + ', '.join(CSV_COLUMNS[1:]))
    common = None
    for ms, _ in cols.values():
        common = ms if common is None else np.intersect1d(common, ms)
    out = {'t': common * (OUTPUT_PERIOD_NS * 1e-9)}
    for col, (ms, v) in cols.items():
        out[col] = v[np.searchsorted(ms, common)]
    return out


def _salvage(file: Path) -> Iterator[Any]:
    """Records of a possibly truncated MCAP file, in file order, up to the first bad byte."""
    from mcap.stream_reader import StreamReader
    with open(file, 'rb') as fh:
        it = StreamReader(fh, skip_magic=False).records
        while True:
            try:
                record = next(it)
            except StopIteration:
                return
            except _mcap_errors():
                return
            yield record


def reindex(path: str | Path) -> dict[str, Any]:
    """Rebuild a readable bag from what an interrupted or killed run left: every complete record
    of the ``.mcap`` (schemas, channels, messages of complete chunks, metadata) is rewritten
    into a new file with its summary and ``metadata.yaml``. Returns the new bag metadata."""
    from mcap.records import Channel, Message, Metadata, Schema
    p = Path(path)
    file = mcap_path(p)
    bag_dir = p if p.is_dir() else p.parent
    schemas: dict[int, Any] = {}
    channels: dict[int, Any] = {}
    messages: list[Any] = []
    metadata: list[Any] = []
    try:
        for rec in _salvage(file):
            if isinstance(rec, Schema):
                schemas[rec.id] = rec
            elif isinstance(rec, Channel):
                channels[rec.id] = rec
            elif isinstance(rec, Message):
                messages.append(rec)
            elif isinstance(rec, Metadata) and rec.name != 'rosbag2':
                metadata.append(rec)
    except OSError as exc:
        raise BagError(f'cannot read {str(file)!r}: {exc.strerror}') from None
    if not channels:
        raise BagError(f'{str(file)!r} holds no readable MCAP channel: nothing to recover')
    messages = [m for m in messages if m.channel_id in channels]
    messages.sort(key=lambda m: m.log_time)
    tmp_dir = bag_dir / '.reindex'
    shutil.rmtree(tmp_dir, ignore_errors=True)
    writer = BagWriter(tmp_dir, file_name=file.name, flush_every_ns=None,
                       library='servovalve_twin reindex')
    try:
        for ch in channels.values():
            schema = schemas.get(ch.schema_id)
            if schema is not None:
                qos = ch.metadata.get('offered_qos_profiles')
                writer.add_topic(ch.topic, schema.name, yaml.safe_load(qos) if qos else None,
                                 definition=schema.data)
        for m in messages:
            topic = channels[m.channel_id].topic
            if topic in writer.channels:
                writer.write(topic, m.data, m.log_time, m.publish_time)
        for md in metadata:
            writer.add_metadata(md.name, md.metadata)
        writer.close()
        shutil.move(str(tmp_dir / file.name), str(file))
        shutil.move(str(tmp_dir / 'metadata.yaml'), str(bag_dir / 'metadata.yaml'))
    finally:
        shutil.rmtree(tmp_dir, ignore_errors=True)
    return writer.bag_metadata()


__all__ = ['BagRun', 'read_bag', 'reindex', 'mcap_path']
