"""servovalve-twin fmu: the FMU, run by FMPy, gives simulate's outputs; parameters
set through the FMU reach the physics; bad input is one line and exit 2, nothing written."""

import numpy as np
import pytest
from fmpy import read_model_description, simulate_fmu

from servovalve_twin.cli import main
from servovalve_twin.config import load_scenario
from servovalve_twin.runs import simulate

PAPER = load_scenario('paper')
OUTPUTS = ['xj', 'dxj', 'p12', 'xs']


@pytest.fixture(scope='module')
def fmus(tmp_path_factory):
    d = tmp_path_factory.mktemp('fmu')
    for model in ('SQ', 'HD'):
        assert main(['fmu', '--valve-model', model, str(d / f'{model}.fmu')]) == 0
    return d


def _run_fmu(path, r, **kw):
    """FMPy on the run's own 1 ms inputs, one communication step per control period."""
    inputs = np.array(list(zip(r['t'], r['com'], r['fr'], r['psr'])),
                      dtype=[('time', float), ('com', float), ('fr', float), ('psr', float)])
    return simulate_fmu(str(path), start_time=0.0, stop_time=float(r['t'][-1]), step_size=1e-3,
                        output_interval=1e-3, input=inputs, output=OUTPUTS, **kw)


@pytest.mark.parametrize('model', ['SQ', 'HD'])
def test_the_fmu_run_by_fmpy_is_simulate(fmus, model):
    """The paper scenario through FMPy equals simulate(ecu_period=1 ms) bit for bit: XS, XJ
    and DXJ at every 1 ms, P12 wherever the supply did not just change (an output is the
    valve's answer at the new state to the supply of the step just taken). Steps of the wrong
    number of DT, an ECU sampled at the wrong instant or inputs applied a step late would
    fail."""
    r = simulate(model, PAPER, ecu_period=1e-3)
    res = _run_fmu(fmus / f'{model}.fmu', r)
    assert np.array_equal(res['time'], r['t'])
    for k in ('xs', 'xj', 'dxj'):
        assert np.array_equal(res[k], r[k]), k
    held = np.concatenate([[True], r['psr'][1:] == r['psr'][:-1]])
    assert (~held).sum() == 2
    assert np.array_equal(res['p12'][held], r['p12'][held])


def test_fmu_parameters_reach_the_physics(fmus):
    """The FMU lists the EHA's parameters (derived ones excepted); a leakage set through it
    (CLk 10x) gives simulate's run with that override, which differs from the nominal one."""
    md = read_model_description(str(fmus / 'SQ.fmu'))
    params = {v.name: v for v in md.modelVariables if v.causality == 'parameter'}
    assert {'CLk', 'M', 'PSRN', 'control_period', 'compressible'} <= set(params)
    assert not {'GM', 'V0', 'C4_alpha'} & set(params)
    clk = float(params['CLk'].start) * 10.0
    r = simulate('SQ', PAPER, {'CLk': clk}, ecu_period=1e-3)
    res = _run_fmu(fmus / 'SQ.fmu', r, start_values={'CLk': clk})
    assert np.array_equal(res['xj'], r['xj'])
    assert not np.array_equal(res['xj'], simulate('SQ', PAPER, ecu_period=1e-3)['xj'])


def test_bad_fmu_input_is_one_line_and_exit_2(fmus, tmp_path, capsys):
    existing = fmus / 'SQ.fmu'
    before = existing.read_bytes()
    cases = [
        (['fmu', '--valve-model', 'SQ', str(existing)], 'exists'),
        (['fmu', '--valve-model', 'XX', str(tmp_path / 'a.fmu')], 'valve model'),
        (['fmu', '--valve-model', 'SQ', str(tmp_path / 'a.zip')], 'must end in .fmu'),
        (['fmu', '--valve-model', 'SQ', '--control-period', '1.5e-5', str(tmp_path / 'a.fmu')],
         'whole multiple of DT'),
    ]
    for args, fragment in cases:
        assert main(args) == 2, args
        err = capsys.readouterr().err
        assert fragment in err and err.count('\n') == 1 and 'Traceback' not in err, err
    assert existing.read_bytes() == before
    assert not list(tmp_path.iterdir())


def test_the_fmu_refuses_steps_and_periods_it_cannot_take(fmus):
    """A control period that is not a multiple of DT fails the initialization, and a
    communication step that is not a whole number of control periods fails the step -- an
    error, not a discard that a master could take for a shorter step."""
    from fmpy.fmi1 import FMICallException
    fmu = str(fmus / 'SQ.fmu')
    with pytest.raises(FMICallException, match='ExitInitializationMode'):
        simulate_fmu(fmu, stop_time=0.01, step_size=1e-3,
                     start_values={'control_period': 1.5e-5})
    with pytest.raises(FMICallException, match='DoStep'):
        simulate_fmu(fmu, stop_time=0.01, step_size=1.5e-3)
