"""servovalve_twin.nodes.process.ros_main: the one shape of the executables that run a body on
a private context (twin, player, replay, servovalve-twin play) -- usage, signals, one error
line, the context shut down and the signal handlers handed back whatever the body did."""

from __future__ import annotations

import os
import signal

import pytest

from servovalve_twin.errors import BagError
from servovalve_twin.nodes.process import ros_main


def test_help_and_stray_arguments_print_the_usage(capsys):
    ran = []
    assert ros_main('x', lambda c, s: ran.append(1), ['x', '-h'], 'usage: x') == 0
    assert capsys.readouterr().out.strip() == 'usage: x'
    assert ros_main('x', lambda c, s: ran.append(1), ['x', 'stray'], 'usage: x') == 2
    assert capsys.readouterr().err.strip() == 'usage: x'
    assert ran == []


def test_a_user_error_is_one_named_line_and_the_context_is_shut_down(capsys):
    seen = {}

    def body(context, stopped):
        seen['context'] = context
        assert context.ok() and not stopped()
        raise BagError('no bag at\n  /nowhere')
    before = signal.getsignal(signal.SIGINT)
    assert ros_main('player', body, ['player', '--ros-args', '-p', 'bag:=/nowhere'],
                    'usage') == 2
    assert capsys.readouterr().err == 'player: error: no bag at /nowhere\n'
    assert not seen['context'].ok()
    assert signal.getsignal(signal.SIGINT) is before


def test_a_signal_stops_the_body_and_rcl_s_refusal_is_one_line(capsys, tmp_path):
    def body(context, stopped):
        os.kill(os.getpid(), signal.SIGTERM)
        assert stopped()
        return 0
    assert ros_main('twin', body, ['twin'], 'usage') == 0
    missing = tmp_path / 'missing.yaml'
    assert ros_main('twin', lambda c, s: 0, ['twin', '--ros-args', '--params-file',
                                             str(missing)], 'usage') == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith('twin: error: ') and 'Traceback' not in err[0]


def test_a_bug_is_not_dressed_as_a_user_error():
    def body(context, stopped):
        raise ZeroDivisionError('a bug')
    with pytest.raises(ZeroDivisionError):
        ros_main('twin', body, ['twin'], 'usage')
