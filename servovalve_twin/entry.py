"""The console scripts' entry points. Importing a node pulls in rclpy and numba -- seconds on a
busy machine -- so each entry point imports its module here, where Ctrl-C during the import is
one line instead of a traceback, and exit code 130 for ``servovalve-twin``, 0 for a ROS
executable (a stop requested before it started is a clean stop).

The ROS executables (nodes, ``twin``, ``player``, ``replay``) leave at once when their ``main``
has returned: their bag is closed, their context shut down and their output flushed, and the
interpreter's own teardown after numba, scipy and rclpy took 2-3 s on a loaded machine (a
launch waits that long on SIGINT). A SIGINT or SIGTERM arriving by then is ignored: the node
is already stopping, and a second Ctrl-C is not an error."""

from __future__ import annotations

import importlib
import logging
import os
import signal
import sys

from . import stopping
from .errors import rcl_refusal


def _run(module: str, func: str = 'main', *, ros: bool = True) -> int:
    stopping.watch()
    try:
        target = getattr(importlib.import_module(module), func)
    except KeyboardInterrupt:
        _interrupted(ros)
    except Exception:
        # a Ctrl-C inside a C extension's initialisation (rclpy's) comes out as its
        # ImportError ('initialization failed'): interrupted all the same
        if stopping.asked():
            _interrupted(ros)
        raise
    if not ros:
        return target()
    try:
        code = target()
    except KeyboardInterrupt:
        # a SIGINT after the import, before the executable set its own handlers
        _interrupted(ros)
    except RuntimeError as exc:
        # rcl's refusal of the command line, wherever the executable hands it over: one
        # line, exit 2
        if (line := rcl_refusal(exc)) is None:
            raise
        print(f'{os.path.basename(sys.argv[0])}: error: {line}', file=sys.stderr)
        code = 2
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_IGN)
    _leave(int(code or 0))


def _interrupted(ros: bool) -> None:
    """Ctrl-C while starting: one line and out -- a second Ctrl-C is ignored (it killed the
    process by its signal, -2, in the interpreter's teardown)."""
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_IGN)
    print('interrupted while starting', file=sys.stderr)
    # a ROS executable asked to stop before it started has stopped cleanly (launch sends
    # SIGINT to every process when one ends: no 'process has died' for this one)
    _leave(0 if ros else 130)


def _leave(code: int) -> None:
    """Exit now: flush what was written, skip the interpreter's teardown."""
    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):       # a closed pipe: nothing more to say
            pass
    os._exit(code)


def one_blas_thread() -> None:
    """OpenBLAS to one thread unless the user set ``OPENBLAS_NUM_THREADS``: before numpy is
    imported, which starts OpenBLAS's pool of a thread per core. The command line's own linear
    algebra is a fit's few-column Jacobians, and starting the pools of numpy's and scipy's
    OpenBLAS cost a ``diagnose`` process 0.16 s of CPU (farm-bench, paired; its JSON identical).
    Not for the ROS executables: ``algorithm`` runs a user's algorithm, which may want them."""
    os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')


def cli() -> int:
    one_blas_thread()
    return _run('servovalve_twin.cli', ros=False)


def command_generator() -> int:
    return _run('servovalve_twin.nodes.sources', 'main_command_generator')


def load_supply() -> int:
    return _run('servovalve_twin.nodes.sources', 'main_load_supply')


def ecu() -> int:
    return _run('servovalve_twin.nodes.ecu')


def plant() -> int:
    return _run('servovalve_twin.nodes.plant')


def clock() -> int:
    return _run('servovalve_twin.nodes.clock')


def monitor() -> int:
    return _run('servovalve_twin.nodes.monitor')


def algorithm() -> int:
    return _run('servovalve_twin.nodes.algorithm')


def player() -> int:
    return _run('servovalve_twin.nodes.player')


def twin() -> int:
    return _run('servovalve_twin.twin.executable')


def replay() -> int:
    return _run('servovalve_twin.apps.replay')
