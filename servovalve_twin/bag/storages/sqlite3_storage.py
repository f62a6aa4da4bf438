"""rosbag2's sqlite3 files (``.db3``): read-only, any schema version."""

from __future__ import annotations

import sqlite3
from pathlib import Path

from ...errors import BagError
from .base import Storage, TopicInfo, normalise_qos


class Sqlite3Storage(Storage):
    """rosbag2's sqlite3 files (``.db3``), opened read-only; any schema version's topics table."""

    name, suffix, magic = 'sqlite3', '.db3', b'SQLite format 3'

    def messages(self, f, keep, start_ns, end_ns, topics_out=None):
        # read-only and immutable: sqlite then writes no -shm or -wal beside the user's bag
        # (a WAL-mode bag opened with mode=ro alone left both); a bag with a -wal beside it
        # was not closed cleanly and its last writes are in that file, which only a plain
        # read-only open reads
        live = Path(str(f) + '-wal').exists()
        uri = Path(f).resolve().as_uri() + ('?mode=ro' if live else '?mode=ro&immutable=1')
        try:
            con = sqlite3.connect(uri, uri=True)
        except sqlite3.Error as exc:
            raise BagError(f'cannot open {str(f)!r} as sqlite3: {exc}') from None
        try:
            cols = {r[1] for r in con.execute('PRAGMA table_info(topics)')}
            if not {'id', 'name', 'type'} <= cols:
                raise BagError(f'{str(f)!r} is not a rosbag2 sqlite3 file (no topics table)')
            qcol = 'offered_qos_profiles' if 'offered_qos_profiles' in cols else "''"
            fcol = 'serialization_format' if 'serialization_format' in cols else "'cdr'"
            names = {}
            for tid, name, typ, fmt, qos in con.execute(
                    f'SELECT id, name, type, {fcol}, {qcol} FROM topics'):
                names[tid] = name
                if topics_out is not None:
                    topics_out.setdefault(name, TopicInfo(name, typ, normalise_qos(qos),
                                                          serialization_format=fmt))
            where, args = [], []
            if keep is not None:
                ids = [i for i, n in names.items() if n in keep]
                where.append(f'topic_id IN ({",".join("?" * len(ids)) or "NULL"})')
                args += ids
            if start_ns is not None:
                where.append('timestamp >= ?')
                args.append(int(start_ns))
            if end_ns is not None:
                where.append('timestamp <= ?')
                args.append(int(end_ns))
            sql = ('SELECT topic_id, timestamp, data, id FROM messages'
                   + (' WHERE ' + ' AND '.join(where) if where else '')
                   + ' ORDER BY timestamp, id')
            last_id: dict[int, int] = {}
            for tid, t, data, rid in con.execute(sql, args):
                if tid not in names or type(t) is not int or t < 0 or type(data) is not bytes:
                    # no checksum: a damaged row is recognised by what it cannot be (a
                    # negative time reached the live view's unsigned stamp: a traceback)
                    raise BagError(f'{str(f)!r} is corrupt: a message row with topic id '
                                   f'{tid!r}, timestamp {t!r}, data of type '
                                   f'{type(data).__name__} (expected a topic of the file, an '
                                   'integer time >= 0 and bytes)')
                # a recorder inserts one topic's messages as they arrive, so their rows and
                # their times rise together; times that fall as the rows rise were rewritten
                # (every timestamp reversed was read as a valid run by evaluate)
                if rid < last_id.get(tid, -1):
                    raise BagError(f'{str(f)!r} is corrupt: on {names[tid]} the message times '
                                   'run backwards against the order the messages were '
                                   'recorded in (altered? sqlite3 keeps no checksum)')
                last_id[tid] = rid
                yield names[tid], t, data
        except sqlite3.DatabaseError as exc:
            raise BagError(f'{str(f)!r} is not a readable rosbag2 sqlite3 file ({exc})'
                           ) from None
        finally:
            con.close()


__all__ = ['Sqlite3Storage']
