"""The storages a bag may use, one reader each, registered in :data:`STORAGES` -- in the spirit
of rosbag2's storage plugins (``get_registered_readers()``): a new storage is a module of its
own here (its :class:`~.base.Storage`) and one entry in the registry, and every command that
takes a bag reads it through :func:`~servovalve_twin.bag.anybag.open_any_bag`.

A storage reads *one file*: its topics and counts (:meth:`Storage.summary`), its messages in
log-time order (:meth:`Storage.messages`) and the bag-level metadata records it carries
(:meth:`Storage.metadata`: MCAP's ``Metadata`` records; sqlite3 has none of its own). Every
failure is one :class:`~servovalve_twin.errors.BagError` line; a CRC that does not hold is
corruption, never read past.

Here: the registry; :mod:`.mcap_storage` and :mod:`.sqlite3_storage`: the formats' readers, on
the interface of :mod:`.base`.
"""

from __future__ import annotations

from pathlib import Path

from ...errors import BagError
from .base import Storage, TopicInfo, normalise_qos
from .mcap_storage import McapStorage, check_data_crc, crc_of, mcap_errors
from .sqlite3_storage import Sqlite3Storage

#: every storage a bag may use, by rosbag2's ``storage_identifier``
STORAGES: dict[str, Storage] = {s.name: s for s in (McapStorage(), Sqlite3Storage())}


def get_registered_readers() -> list[str]:
    """The storage identifiers this package reads (rosbag2's function of the same name)."""
    return sorted(STORAGES)


def storage_of(f: Path) -> Storage:
    """The storage of a file, by its suffix or else its first bytes."""
    for s in STORAGES.values():
        if f.suffix == s.suffix:
            return s
    with open(f, 'rb') as fh:
        head = fh.read(16)
    for s in STORAGES.values():
        if head.startswith(s.magic):
            return s
    if head.startswith(b'#ROSBAG'):
        raise BagError(f'{str(f)!r} is a ROS 1 bag, not a rosbag2 bag')
    raise BagError(f'{str(f)!r} is not a rosbag2 storage file ('
                   + ' or '.join(s.suffix for s in STORAGES.values()) + ')')


__all__ = ['STORAGES', 'Storage', 'TopicInfo', 'get_registered_readers', 'storage_of',
           'normalise_qos', 'check_data_crc', 'crc_of', 'mcap_errors']
