"""A stop asked for while a process starts is never lost.

Until an executable installs its own SIGINT handler (after importing rclpy and numba and
building its context: a second or more on a busy machine), Python's default one raises
KeyboardInterrupt wherever the interpreter happens to be -- and where that is a weakref
callback (importlib's module locks have one) Python prints "Exception ignored" and carries on:
the node then started and ran for ever, deaf to the Ctrl-C it had been sent (seen once in 60
signals at random instants of a plant's start). So the entry points install :func:`watch`
first: it raises KeyboardInterrupt as before *and* remembers the request, and each executable,
once its own handler is in place (:func:`handle`), asks :func:`asked` whether a stop came
before it."""

from __future__ import annotations

import signal
from typing import Any, Callable

_ASKED: list[int] = []


def _ask(signum, frame) -> None:
    _ASKED.append(signum)
    # a second Ctrl-C while this one unwinds (a launch's, 50 ms later) is noted, not raised:
    # raised inside the handler of the first it was a traceback and exit 1
    signal.signal(signal.SIGINT, _note)
    raise KeyboardInterrupt


def _note(signum, frame) -> None:
    _ASKED.append(signum)


def watch() -> None:
    """Remember every SIGINT from now until the process installs its own handler."""
    signal.signal(signal.SIGINT, _ask)


def asked() -> bool:
    """Whether a SIGINT arrived while :func:`watch` was the handler."""
    return bool(_ASKED)


def handle(request_stop: Callable[..., Any]) -> dict[int, Any]:
    """Hand SIGINT and SIGTERM to ``request_stop`` -- and call it at once (without
    arguments) where a Ctrl-C came while starting: the one way an executable takes its signals
    over. Returns the handlers it replaced (to restore)."""
    old = {sig: signal.signal(sig, request_stop) for sig in (signal.SIGINT, signal.SIGTERM)}
    if asked():
        request_stop()
    return old


__all__ = ['watch', 'asked', 'handle']
