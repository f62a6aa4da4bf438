"""A command's output file is whole or absent: it is written beside the target under a
temporary name and renamed onto it once complete (a rename within one directory is atomic).
A full disk, an error or a kill midway leaves the target as it was and no temporary file;
a target that is a symbolic link is replaced as a link, never written through.

``output_file(path)`` for text written here, ``output_path(path)`` for a library that writes
a file itself (pyarrow, matplotlib), ``place_new(built, path)`` for a file built elsewhere that
must not replace an existing one (the FMU), ``write_new(path, text)`` for text that must not
(a designed test, monitor thresholds, a report page).
"""

from __future__ import annotations

import contextlib
import errno
import json
import math
import os
import secrets
import shutil
import stat
from pathlib import Path
from typing import IO, Any, Iterator

from .errors import TwinError


#: the errors of a file system that has no room for what is written
DISK_FULL = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)


def write_failed(target: str | Path, exc: OSError, kept: str = 'nothing of it was written'
                 ) -> TwinError:
    """The one line of a write to ``target`` that failed: "no space left" where the disk
    (or a quota, or the file size limit) is full, else the system's reason; never the name of
    a temporary file."""
    why = ('no space left on its device' if exc.errno == errno.ENOSPC else
           'the disk quota is exceeded' if exc.errno == errno.EDQUOT else
           'the file size limit is reached' if exc.errno == errno.EFBIG else
           exc.strerror or str(exc))
    return TwinError(f'{target}: {why} ({kept})')


def short_write(target: str | Path, exc: OSError) -> TwinError:
    """:func:`write_failed` of a write that reported no errno (numpy's ``tofile``: "1001
    requested and 0 written"): a full disk where the target's file system has no room left."""
    if not exc.errno:
        try:
            st = os.statvfs(Path(target).parent)
            if st.f_bavail * st.f_frsize < (1 << 20):
                exc = OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        except OSError:
            pass
    return write_failed(target, exc)


def new_temporary(directory: Path, prefix: str, suffix: str) -> tuple[int, Path]:
    """A new file in ``directory`` under a random name, opened for writing: ``(fd, path)``.
    Created exclusively (never an existing file or a planted link), with the permissions a
    new file gets from the user's umask (0644 with the usual 022) -- ``mkstemp``'s 0600 made
    every output, once renamed into place, readable by its owner alone."""
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, 'O_NOFOLLOW', 0)
    for _ in range(100):
        tmp = directory / f'{prefix}{secrets.token_hex(6)}{suffix}'
        try:
            return os.open(tmp, flags, 0o666), tmp
        except FileExistsError:
            continue
    raise FileExistsError(errno.EEXIST, 'no free temporary name', str(directory))


def _kind(mode: int) -> str | None:
    """What a file of ``mode`` is, where it is not something an output may replace (a
    regular file, or a symbolic link, replaced as a link)."""
    for test, name in ((stat.S_ISDIR, 'a directory'), (stat.S_ISFIFO, 'a FIFO'),
                       (stat.S_ISSOCK, 'a socket'), (stat.S_ISCHR, 'a character device'),
                       (stat.S_ISBLK, 'a block device')):
        if test(mode):
            return name
    return None


def refuse_special(path: Path) -> None:
    """Refuse an output path that exists and is not a regular file: renaming onto a device,
    a FIFO or a socket would replace it (``--out /dev/full`` said "1001 rows" and, as root,
    replaced the device node with a CSV)."""
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return
    kind = _kind(mode)
    if kind is not None:
        raise TwinError(f'{path} is {kind}; give the name of a regular file (new or to replace)')


def _temporary(path: Path) -> Path:
    refuse_special(path)
    try:
        # the target's suffix kept last: a writer that infers the format from it (matplotlib)
        fd, tmp = new_temporary(path.parent, f'.{path.stem}.', f'.part{path.suffix}')
    except OSError as exc:                  # the error names the target, not our temporary
        raise OSError(exc.errno, exc.strerror, str(path)) from None
    os.close(fd)
    return tmp


@contextlib.contextmanager
def output_path(path: str | Path) -> Iterator[Path]:
    """A temporary path beside ``path`` to write to; renamed onto ``path`` when the block
    ends without an error, removed otherwise."""
    path = Path(path)
    existed = path.exists() or path.is_symlink()
    tmp = _temporary(path)
    try:
        yield tmp
        os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        # (the error named our temporary, .run.a1b2c3.part.csv, not the user's file)
        raise write_failed(path, exc, f'{path.name} is as it was' if existed else
                           'nothing of it was written') from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


@contextlib.contextmanager
def output_file(path: str | Path, mode: str = 'w', *, newline: str | None = None,
                encoding: str | None = 'utf-8') -> Iterator[IO]:
    """An open file whose content replaces ``path`` only once the block has ended without an
    error."""
    with output_path(path) as tmp:
        with open(tmp, mode, newline=newline,
                  encoding=None if 'b' in mode else encoding) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())


def place_new(built: str | Path, path: str | Path) -> Path:
    """Move the finished file ``built`` to ``path``, which must not exist: copied beside it
    under a temporary name (``built`` may be on another filesystem), then linked into place --
    a link fails rather than replace a file that appeared meanwhile."""
    path = Path(path)
    tmp = _temporary(path)
    try:
        shutil.copyfile(built, tmp)
        try:
            os.link(tmp, path)
        except FileExistsError:
            raise TwinError(f'{path} exists; give a new file name (nothing is overwritten)'
                            ) from None
    except OSError as exc:
        # (the error named the build's temporary directory, /tmp/svt_fmu_.../x.fmu)
        raise write_failed(path, exc) from None
    finally:
        tmp.unlink(missing_ok=True)
    return path


def discard_directory(directory: Path, created: bool) -> None:
    """Remove what a command wrote into ``directory``, which was new or empty when it began
    (so every regular file in it is the command's), and the directory itself if the command
    created it and nothing else appeared there: an output directory is whole or absent."""
    for f in directory.iterdir() if directory.is_dir() else ():
        if f.is_file() and not f.is_symlink():
            f.unlink()
    if created:
        try:
            directory.rmdir()
        except OSError:
            pass                        # something else was put there meanwhile: keep it


def write_new(path: Path, text: str) -> None:
    """``text`` into a new file (never an existing one, nor through a symbolic link); on
    any failure the half-written file, ours, is removed."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, 'O_NOFOLLOW', 0),
                 0o644)
    try:
        with os.fdopen(fd, 'w', encoding='utf-8') as fh:
            fh.write(text)
    except BaseException:
        path.unlink(missing_ok=True)
        raise


def json_ready(o: Any) -> Any:
    """``o`` with NaN and infinities as None (JSON null: JSON has no such numbers)."""
    if isinstance(o, float) and not math.isfinite(o):
        return None
    if isinstance(o, dict):
        return {k: json_ready(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [json_ready(v) for v in o]
    return o


def write_json(path: str | Path, payload: Any) -> None:
    """``payload`` as indented JSON (:func:`json_ready`) to a new ``path``, whole or absent."""
    with output_file(path) as fh:
        fh.write(json.dumps(json_ready(payload), indent=2) + '\n')


__all__ = ['output_file', 'output_path', 'place_new', 'write_new', 'json_ready', 'write_json']
