"""The watch over a user's algorithm while it runs
(:mod:`~servovalve_twin.prognostics.algorithm`): a step, a block of steps, its import or its
setup that makes no progress ends the run with one line, and ``os._exit`` called from it is
refused -- the host, not the algorithm, ends a run.
"""

from __future__ import annotations

import contextlib
import itertools
import os
import threading
import time
from typing import TYPE_CHECKING, Callable, Iterator, Sequence

from .algorithm import AlgorithmError

if TYPE_CHECKING:
    from .algorithm import AlgorithmRunner

#: a user's algorithm that makes no progress for this long [wall s] -- one step, one block of
#: steps, its import or its setup -- ends the run with one line (one that blocked in step()
#: held evaluate for ever)
STEP_LIMIT_S = 30.0


class _Stalled(BaseException):
    """Raised in the main thread by :class:`Watchdog`'s signal (not an Exception: the user's
    code may catch those)."""


class Watchdog:
    """``with Watchdog(beats, what):`` -- a thread that signals the main thread (SIGUSR1,
    whose handler is set for the block) when ``beats()`` (a counter the watched code
    advances) has not moved for :data:`STEP_LIMIT_S`, which ends the block with one
    :class:`AlgorithmError` line. A signal interrupts a blocking call (a sleep, a read) as
    well as a loop; a C extension that holds the interpreter and never checks is not
    stopped. Only in the main thread (elsewhere it watches nothing)."""

    def __init__(self, beats: Callable[[], int], what: str, limit: float | None = None):
        self.beats, self.what = beats, what
        self.limit = STEP_LIMIT_S if limit is None else limit
        self._stop = threading.Event()
        self._thread = None
        self._old = None

    def __enter__(self):
        import signal
        if threading.current_thread() is threading.main_thread() and hasattr(signal,
                                                                              'pthread_kill'):
            self._old = signal.signal(signal.SIGUSR1, self._raise)
            self._main = threading.get_ident()
            self._thread = threading.Thread(target=self._watch, name='algorithm-watchdog',
                                            daemon=True)
            self._thread.start()
        return self

    @staticmethod
    def _raise(signum, frame):
        raise _Stalled()

    def _watch(self) -> None:
        import signal
        last, since = self.beats(), time.monotonic()
        while not self._stop.wait(min(0.25, self.limit / 4)):
            now = self.beats()
            if now != last:
                last, since = now, time.monotonic()
            elif time.monotonic() - since > self.limit:
                signal.pthread_kill(self._main, signal.SIGUSR1)
                return

    def __exit__(self, kind, exc, tb):
        import signal
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            signal.signal(signal.SIGUSR1, self._old)
        if kind is _Stalled:
            raise AlgorithmError(f'{self.what} made no progress for {self.limit:g} s (a step '
                                 'that blocks or never ends?): the run is stopped') from None
        return False


def in_step_beats(runners: Sequence['AlgorithmRunner']) -> Callable[[], int]:
    """A :class:`Watchdog`'s beats for algorithms stepped among other work (the twin's
    lockstep): their steps while one of them is inside ``step``, else a count that always
    moves -- the twin waiting for a follower or pacing to the wall clock is no stall."""
    idle = itertools.count()

    def beats() -> int:
        if any(r.in_step for r in runners):
            return sum(r.beats for r in runners)
        return -1 - next(idle)
    return beats


@contextlib.contextmanager
def exits_refused(what: str) -> Iterator[None]:
    """``os._exit`` raises instead of ending the process while a user's algorithm runs: it
    skips every handler, so a run it ended left a bag without ``metadata.yaml`` and said
    nothing (rc 0). ``sys.exit`` is a SystemExit, which the runner already names."""
    real = os._exit

    def refused(code=0):
        raise AlgorithmError(f'{what} called os._exit({code}): a run is ended by the twin, '
                             'not by an algorithm (raise an exception to stop it)')
    os._exit = refused
    try:
        yield
    finally:
        os._exit = real


__all__ = ['Watchdog', 'in_step_beats', 'exits_refused', 'STEP_LIMIT_S']
