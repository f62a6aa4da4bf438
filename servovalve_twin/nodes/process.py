"""The two shapes of a ROS process, each written once: a node run alone, as ``ros2 run`` runs
it (:func:`spin_standalone`: the node executables), and an executable that runs a body of its
own on a private context (:func:`ros_main`: ``twin``, ``player``, ``replay`` and
``servovalve-twin play``) -- usage, signals, context, one error-line format, the shutdown in
order."""

from __future__ import annotations

import signal
import sys
from pathlib import Path
from typing import Callable, Sequence

import rclpy
from rclpy.context import Context
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import remove_ros_args

from .. import stopping
from ..errors import TwinError, one_line, rcl_refusal
from .rosargs import asks_for_help, init_context, stray_arguments

#: what a user's input can do wrong at start-up: one error line, exit 2 ((the last) a
#: parameter's type or range refused at declare time)
_REFUSED = (TwinError, rclpy.exceptions.ParameterException)

def _refuse_unknown_parameters(node: Node) -> None:
    """A ``-p NAME:=VALUE`` the node does not declare is a misspelling, unless it is a physical
    parameter another node reads (one ``--params-file config/eha.yaml`` serves every node)."""
    from ..physics.params import PARAM_NAMES
    given = getattr(node, '_parameter_overrides', {}) or {}
    unknown = sorted(n for n in given if not node.has_parameter(n) and n not in PARAM_NAMES
                     and not n.startswith('qos_overrides.'))
    if unknown:
        declared = sorted(n for n in node._parameters if n not in PARAM_NAMES)
        raise TwinError(f'node {node.get_name()} has no parameter {unknown[0]!r}; it declares '
                        f'{declared} and the physical parameters it reads')


def describe(node: Node) -> str:
    """What a node runs with, in one line: its models, control period and time source."""
    parts = []
    for name in ('valve_model', 'monitor_model', 'scenario'):
        if node.has_parameter(name):
            parts.append(f'{name} {node.get_parameter(name).value}')
    if node.has_parameter('control_period'):
        parts.append(f'control period {node.get_parameter("control_period").value:g} s')
    sim = node.get_parameter('use_sim_time').value
    parts.append('simulated time (/clock)' if sim else 'wall time')
    return ', '.join(parts)


def spin_standalone(factory: Callable[[], Node], args: Sequence[str] | None = None) -> int:
    """Jazzy's idiom for a node run alone (``ros2 run`` / console script): SIGINT and SIGTERM
    end it cleanly; bad parameters at start-up are one line and exit code 2.

    rclpy's own signal handler shuts the context down under the executor, which then fails to
    build its wait set (a race seen with SIGTERM), and an exception raised by a Python handler
    inside a callback surfaces from pybind11 as a RuntimeError. So both signals only set a flag;
    the executor waits at most 0.1 s at a time (a sim-time timer whose ``/clock`` stopped never
    fires), sees it and leaves, and the ``finally`` below shuts down in order.
    """
    argv = list(args) if args is not None else list(sys.argv)
    plain = argv[1:argv.index('--ros-args')] if '--ros-args' in argv else argv[1:]
    if plain:
        doc = (getattr(factory, '__doc__', None) or '').strip()
        print(f'usage: {Path(argv[0]).name} [--ros-args -p NAME:=VALUE ... '
              f'[--params-file FILE]]\n\n{doc}')
        return 0 if plain[0] in ('-h', '--help') else 2
    stop = []

    def request_stop(*_):
        stop.append(True)
    stopping.handle(request_stop)
    try:
        # parsed first on their own: rcl_init would log its own error line before refusing
        remove_ros_args(argv)
        rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    except RuntimeError as exc:                  # e.g. a params file that is missing
        if (line := rcl_refusal(exc)) is None:
            raise
        print(f'error: {line}', file=sys.stderr)
        return 2
    node = executor = None
    if stop:            # asked to stop while rclpy started: do not build (and compile) a node
        rclpy.try_shutdown()
        return 0
    try:
        node = factory()
        _refuse_unknown_parameters(node)
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        # one start-up line; it also tells a supervisor (and the tests) that the signal
        # handlers are in place and the node is up
        node.get_logger().info('started: ' + describe(node))
        while rclpy.ok() and not stop:
            executor.spin_once(timeout_sec=0.1)
    except ExternalShutdownException:
        pass
    except _REFUSED as exc:
        print(f'error: {one_line(exc)}', file=sys.stderr)
        return 2
    finally:
        if executor is not None:
            executor.shutdown()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


def ros_main(name: str, body: Callable[[Context, Callable[[], bool]], int],
             args: Sequence[str] | None = None, usage: str | None = None) -> int:
    """An executable that runs ``body(context, stopped)`` on a private rclpy context, built
    from ``args`` (default ``sys.argv``): ``-h`` prints ``usage`` (exit 0) and any argument
    outside ``--ros-args`` is refused with it (exit 2); SIGINT and SIGTERM make ``stopped()``
    true (a body that installs handlers of its own -- a twin's -- asks it until then) and
    are handed back when it returns; a user's error (a :class:`TwinError`, a refused
    parameter, rcl's refusal of the command line) is one line ``NAME: error: ...``, exit 2;
    the context is shut down whatever happens. ``usage`` None: a command of the command line
    (its own parser read the arguments; rcl gets none -- by default it read sys.argv and took
    the command's own ``--remap FROM:=TO`` for a remap rule)."""
    argv = list(sys.argv if args is None else args)
    try:
        if usage is not None:
            if asks_for_help(argv):
                print(usage)
                return 0
            if stray_arguments(argv):
                print(usage, file=sys.stderr)
                return 2
        return _run_body(name, body, argv if usage is not None else [name])
    except _REFUSED as exc:
        print(f'{name}: error: {one_line(exc)}', file=sys.stderr)
        return 2
    except RuntimeError as exc:
        if (line := rcl_refusal(exc)) is None:
            raise
        print(f'{name}: error: {line}', file=sys.stderr)
        return 2


def _run_body(name: str, body: Callable[[Context, Callable[[], bool]], int],
              argv: list[str]) -> int:
    stop: list[bool] = []
    old = stopping.handle(lambda *_: stop.append(True))
    context = None
    try:
        context, _ = init_context(argv)
        return int(body(context, lambda: bool(stop)) or 0)
    finally:
        if context is not None:
            rclpy.try_shutdown(context=context)
        for sig, handler in old.items():
            signal.signal(sig, handler)


__all__ = ['spin_standalone', 'ros_main', 'describe']
