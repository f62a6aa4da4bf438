"""Reading the twin's bags back (rebuilding one cut short is :mod:`.reindex`).

A bag is a directory holding ``<name>_0.mcap`` and ``metadata.yaml`` (or the ``.mcap`` file
itself). Every failure -- missing file, truncated or corrupt MCAP, a bag of another layout --
is a :class:`~servovalve_twin.errors.BagError` with a one-line reason, never a traceback.
"""

from __future__ import annotations

import dataclasses
import struct
import zlib
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ..errors import BagError
from .cdr import decode_float64
from .table import signal_table

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


def check_data_crc(file: Path) -> None:
    """Verify an MCAP file's data-section CRC (the DataEnd record's), which covers what lies
    outside the chunks -- the metadata records, the twin's provenance among them. The mcap
    reader checks the chunk and summary CRCs but does not read the whole data section. A CRC of
    0 means "not computed" (rosbag2 writes 0; so did this project before CRCs)."""
    with open(file, 'rb') as fh:
        data = fh.read()
    if len(data) < 8 + 29 + 8 or data[-8:] != data[:8]:
        return                                  # no footer: the reader will say what is wrong
    footer = data[-8 - 29:-8]
    if footer[0] != 0x02:
        return
    summary_start = struct.unpack('<Q', footer[9:17])[0]
    end = summary_start - 13 if summary_start else len(data) - 8 - 29 - 13
    if end < 8 or data[end] != 0x0F:
        raise BagError(f'bag {str(file)!r} is corrupt (no DataEnd record where the footer '
                       'points)')
    stored = struct.unpack('<I', data[end + 9:end + 13])[0]
    if stored and zlib.crc32(data[:end]) != stored:
        raise BagError(f'bag {str(file)!r} is corrupt: the CRC of its data section does not '
                       'match (a byte was changed outside the message chunks)')


def read_provenance(file: Path) -> dict[str, str]:
    """The twin's provenance record of an MCAP file ({} when it has none), CRCs checked."""
    from mcap.reader import make_reader
    try:
        check_data_crc(file)
        with open(file, 'rb') as fh:
            for meta in make_reader(fh, validate_crcs=True).iter_metadata():
                if meta.name == PROVENANCE:
                    return dict(meta.metadata)
    except OSError as exc:
        raise BagError(f'cannot read bag {str(file)!r}: {exc.strerror}') from None
    except _mcap_errors() as exc:
        raise BagError(f'bag {str(file)!r} is truncated or corrupt ({type(exc).__name__}: '
                       f'{str(exc)[:120]})') from None
    return {}


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
            head = fh.read(8)
        if head.startswith(b'#ROSBAG'):
            raise BagError(f'{str(file)!r} is a ROS 1 bag, not a rosbag2 bag')
        if head and not head.startswith(b'\x89MCAP'):
            raise BagError(f'{str(file)!r} is not an MCAP file (a rosbag2 bag of the twin is '
                           'MCAP; `servovalve-twin play` and `evaluate` also read sqlite3)')
        check_data_crc(file)
        with open(file, 'rb') as fh:
            reader = make_reader(fh, validate_crcs=True)
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
    return BagRun(path=p, signals=signal_table(arrays), topics=counts, provenance=provenance,
                  series=arrays)


__all__ = ['BagRun', 'read_bag', 'mcap_path', 'PROVENANCE']
