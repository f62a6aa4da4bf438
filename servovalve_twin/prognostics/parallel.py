"""Many independent ROS-free runs, on local processes or on a Dask cluster, their results taken
as they finish: what a sweep's cases and a flight calibration's units share.

Why one module: both need the same things done the same way -- workers that end with their
parent and leave Ctrl-C to it, SIGTERM and SIGHUP handled as Ctrl-C, a cluster address checked
before anything runs, a lost scheduler or a cluster without workers named in one line -- and
both need results *as they finish*: taken in submission order, one slow run held back every
result behind it. On a cluster, several items go in one task (``batch``): a run of 20 ms costs
~15 ms of Dask's own CPU per task.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from typing import Any, Callable, Iterable, Iterator, Mapping, Sequence

from ..errors import TwinError

#: how long a Dask cluster may have no worker at all before the work gives up on it [s]
NO_WORKER_S = 60.0
#: how long to wait for a Dask scheduler to answer at first [s]
CONNECT_S = 10.0


class SchedulerLost(TwinError):
    """The Dask scheduler went away mid-run: the items it had not returned are lost."""


class Signalled(KeyboardInterrupt):
    """SIGTERM or SIGHUP, raised where Ctrl-C would be, so that work stopped by ``docker
    stop``, systemd or a CI time-out ends as an interrupted one does: its workers with it,
    what finished written whole. ``signum``: the signal."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def interrupt_code(exc: KeyboardInterrupt) -> int:
    """The exit code of work stopped by ``exc``: 128 + the signal (130 for Ctrl-C, 143 for
    SIGTERM, 129 for SIGHUP)."""
    return 128 + (exc.signum if isinstance(exc, Signalled) else signal.SIGINT)


def _raise_signalled(signum, _frame):
    raise Signalled(signum)


def stop_on_signals() -> dict:
    """SIGTERM and SIGHUP raise :class:`Signalled` in the main thread (what they did: end the
    process at once, its pool workers left running with PPID 1 and its outputs half
    written); returns the handlers replaced, for :func:`restore_signals`."""
    return {sig: signal.signal(sig, _raise_signalled) for sig in (signal.SIGTERM, signal.SIGHUP)}


def restore_signals(old: Mapping) -> None:
    for sig, handler in old.items():
        signal.signal(sig, handler)


def worker_init() -> None:
    """A pool worker: Ctrl-C is the parent's to decide (it stops the items not started and
    waits for these); SIGTERM and SIGHUP end it; and it ends with its parent (Linux's
    parent-death signal), so that a parent killed outright (SIGKILL) leaves no worker."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    for sig in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, signal.SIG_DFL)
    try:
        import ctypes
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGTERM)           # PR_SET_PDEATHSIG
        if os.getppid() == 1:                   # the parent died before the call
            os._exit(1)
    except (OSError, AttributeError):           # not Linux: the pool's own shutdown serves
        pass


def bad_scheduler(scheduler: str, exc: Exception) -> str:
    return (f'--scheduler {scheduler!r} is not an address (expected tcp://HOST:PORT): '
            f'{exc}')


def check_scheduler(scheduler: str) -> None:
    """Refuse a Dask scheduler address that is no address at all ('::::'), before anything
    is written."""
    try:
        from distributed.comm.addressing import parse_address, parse_host_port
    except ImportError:
        return
    try:
        parse_host_port(parse_address(scheduler)[1])
    except (ValueError, TypeError) as exc:
        raise TwinError(bad_scheduler(scheduler, exc)) from None


def connect(scheduler: str):
    """A Dask client of ``scheduler``, or one line saying why not."""
    try:
        from dask.distributed import Client
    except ImportError:
        raise TwinError('--scheduler needs dask.distributed: pip install '
                        "'dask[distributed]'") from None
    try:
        return Client(scheduler, timeout=CONNECT_S)
    except (OSError, TimeoutError) as exc:
        raise TwinError(f'cannot reach the Dask scheduler at {scheduler}: {exc}') from None
    except ValueError as exc:           # '::::' is no address at all
        raise TwinError(bad_scheduler(scheduler, exc)) from None


def _batch(fn: Callable[[Any], Any], items: Sequence[Any]) -> list[Any]:
    return [fn(x) for x in items]


def map_unordered(fn: Callable[[Any], Any], items: Iterable[Any], *,
                  workers: int | None = None, scheduler: str | None = None,
                  batch: int = 1, in_flight: int = 4) -> Iterator[Any]:
    """``fn(item)`` for every item, yielded as each finishes (not in order): on the Dask
    cluster at ``scheduler`` in tasks of ``batch`` items, else on a local pool of ``workers``
    processes (default: one per core; 1: here, in order) with at most ``in_flight`` items per
    worker submitted at a time (10^5 items never make 10^5 futures). ``fn`` must be
    picklable (a module-level function). Closing the stream early (Ctrl-C in the consumer)
    drops the items not started and waits only for those running."""
    items = list(items)
    if scheduler:
        yield from _on_cluster(fn, items, scheduler, max(1, batch))
        return
    workers = workers or os.cpu_count() or 1
    if workers == 1 or len(items) <= 1:
        for x in items:
            yield fn(x)
        return
    # forked: the parent's loaded (compiled) physics is shared, not loaded again per worker
    ctx = multiprocessing.get_context('fork') if 'fork' in \
        multiprocessing.get_all_start_methods() else None
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=worker_init)
    try:
        todo = iter(items)
        pending: set = set()
        while True:
            for x in todo:
                pending.add(pool.submit(fn, x))
                if len(pending) >= in_flight * workers:
                    break
            if not pending:
                return
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for f in done:
                yield f.result()
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _on_cluster(fn, items: list, scheduler: str, batch: int) -> Iterator[Any]:
    from concurrent.futures import CancelledError
    from distributed import TimeoutError as DaskTimeout
    from distributed import wait as dask_wait
    client = connect(scheduler)
    try:
        chunks = [items[i:i + batch] for i in range(0, len(items), batch)]
        pending = set(client.map(_batch, [fn] * len(chunks), chunks, pure=False))
        since = None
        while pending:
            try:
                done, pending = dask_wait(pending, timeout=5, return_when='FIRST_COMPLETED')
            except (DaskTimeout, TimeoutError):     # (an OSError too: caught first)
                # a cluster left without any worker (they died and nothing restarts them) is
                # an error after NO_WORKER_S, not a wait for ever
                if client.scheduler_info().get('workers'):
                    since = None
                elif since is None:
                    since = time.monotonic()
                elif time.monotonic() - since > NO_WORKER_S:
                    raise TwinError(f'the Dask cluster at {scheduler} has had no worker for '
                                    f'{NO_WORKER_S:g} s: start workers, or run locally '
                                    '(without --scheduler)') from None
                continue
            except (CancelledError, OSError) as exc:
                # the scheduler went away while waiting (its comm closed)
                raise SchedulerLost(f'lost the Dask scheduler at {scheduler} '
                                    f'({type(exc).__name__})') from None
            for f in done:
                try:
                    yield from f.result()
                except (CancelledError, OSError) as exc:
                    # the scheduler went away: its futures are cancelled
                    raise SchedulerLost(f'lost the Dask scheduler at {scheduler} '
                                        f'({type(exc).__name__})') from None
    finally:
        client.close()


__all__ = ['map_unordered', 'connect', 'check_scheduler', 'worker_init', 'stop_on_signals',
           'restore_signals', 'interrupt_code', 'Signalled', 'SchedulerLost', 'NO_WORKER_S']
