"""servovalve-twin fmu: the FMU, run by FMPy, gives simulate's outputs; parameters
set through the FMU reach the physics; bad input is one line and exit 2, nothing written."""

from pathlib import Path

import numpy as np
import pytest
import yaml
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


SENSORS = {'seed': 4, 'xj': {'noise': 2.0e-5, 'quantisation': 1.0e-6},
           'xs': {'bias': 1.0e-6, 'drift': 1.0e-5}, 'p12': {'noise': 1.0e5, 'period': 0.002}}


def test_an_fmu_with_sensors_is_simulate_with_them(tmp_path):
    """An FMU built with --sensors, stepped 3 ms at a time (so that a 2 ms P12 sample falls
    inside a step), outputs simulate()'s readings at each step's end, and its ECU closes the
    loop on them (the true XJ would differ); its sensor_seed parameter is simulate's
    sensor_seed."""
    (tmp_path / 's.yaml').write_text(yaml.safe_dump(SENSORS))
    fmu = tmp_path / 'SQs.fmu'
    assert main(['fmu', '--valve-model', 'SQ', '--sensors', str(tmp_path / 's.yaml'),
                 str(fmu)]) == 0
    for seed in (None, 11):
        r = simulate('SQ', dict(PAPER.to_dict(), sensors=SENSORS),
                     ecu_period=1e-3, sensor_seed=seed)
        inputs = np.array(list(zip(r['t'], r['com'], r['fr'], r['psr'])),
                          dtype=[('time', float), ('com', float), ('fr', float),
                                 ('psr', float)])
        res = simulate_fmu(str(fmu), start_time=0.0, stop_time=0.999, step_size=3e-3,
                           output_interval=3e-3, input=inputs, output=OUTPUTS,
                           start_values={} if seed is None else {'sensor_seed': seed})
        rows = np.rint(res['time'] * 1000).astype(int)
        assert set(rows.tolist()) >= set(range(0, 1000, 3))    # and the input events
        for k in ('xs', 'xj', 'dxj'):
            assert np.array_equal(res[k], r[k][rows]), (seed, k)
        # P12 wherever the supply did not just change (as without sensors)
        held = r['psr'][rows] == r['psr'][np.maximum(rows - 1, 0)]
        assert (~held).sum() == 2
        assert np.array_equal(res['p12'][held], r['p12'][rows][held]), seed
        assert not np.array_equal(res['xj'], r.truth['xj'][rows])


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
    # a failed run leaves the FMU unpacked, its resources first on this process's path: its
    # copy of the physics must not be a servovalve_twin there, or a process spawned from here
    # (a Dask worker) imports the copy and fails on servovalve_twin.prognostics
    # (a colcon workspace has the package twice, in src/ and install/: both whole)
    import sys
    shadows = [p for p in sys.path if p and (Path(p) / 'servovalve_twin').is_dir()
               and not (Path(p) / 'servovalve_twin' / 'prognostics').is_dir()]
    assert shadows == []


#: what the importer's Python runs: validate, then simulate on the inputs in inputs.npz
IMPORTER = '''
import json, sys
import numpy as np
from fmpy import simulate_fmu
from fmpy.validation import validate_fmu
fmu, inputs, out = sys.argv[1:4]
log = []
problems = validate_fmu(fmu)
x = np.load(inputs)
rows = np.array(list(zip(x['t'], x['com'], x['fr'], x['psr'])),
                dtype=[('time', float), ('com', float), ('fr', float), ('psr', float)])
try:
    res = simulate_fmu(fmu, start_time=0.0, stop_time=float(x['t'][-1]), step_size=1e-3,
                       output_interval=1e-3, input=rows, output=['xj', 'dxj', 'p12', 'xs'],
                       logger=lambda *a: log.append(a[-1].decode(errors='replace')
                                                    if isinstance(a[-1], bytes) else str(a[-1])),
                       debug_logging=True)
    np.savez(out, **{k: res[k] for k in res.dtype.names})
    error = None
except Exception as exc:
    error = str(exc)
print(json.dumps(dict(problems=problems, error=error, log=log[-20:])))
'''


def _fmu_python() -> Path:
    """The FMU venv's Python: $FMU_VENV's (scripts/test makes it), else this checkout's
    .venv-fmu, built here by scripts/fmu-venv when missing -- so that ``colcon test`` on a ROS
    machine, where no project script ran first, needs nothing more. Skipped, with the reason,
    only where it cannot be built (no network to PyPI)."""
    import os
    import subprocess
    from conftest import ROOT
    if os.environ.get('FMU_VENV'):
        return Path(os.environ['FMU_VENV']) / 'bin' / 'python'
    venv = ROOT / '.venv-fmu'
    if not (venv / '.installed').exists():
        built = subprocess.run([str(ROOT / 'scripts' / 'fmu-venv')], capture_output=True,
                               text=True, timeout=1800)
        if built.returncode != 0:
            pytest.skip('the FMU importer venv (FMPy, numpy, numba) could not be built: '
                        + ' '.join(built.stderr.split())[-300:])
    return venv / 'bin' / 'python'


def _importer(fmu, r, tmp_path, extra_path=None):
    """Run the FMU with FMPy in the FMU venv (scripts/fmu-venv): a Python that has FMPy and
    the FMU's declared packages, not servovalve_twin. ``extra_path`` goes first on its path."""
    import json
    import os
    import subprocess
    py = _fmu_python()
    env = {k: v for k, v in os.environ.items() if k not in ('PYTHONPATH', 'VIRTUAL_ENV')}
    if extra_path:
        env['PYTHONPATH'] = str(extra_path)
    np.savez(tmp_path / 'inputs.npz', t=r['t'], com=r['com'], fr=r['fr'], psr=r['psr'])
    probe = subprocess.run([str(py), '-c', 'import servovalve_twin'], cwd=tmp_path, env=env,
                           capture_output=True, text=True)
    assert probe.returncode != 0, 'the FMU venv must not have servovalve_twin'
    (tmp_path / 'importer.py').write_text(IMPORTER)
    out = subprocess.run([str(py), str(tmp_path / 'importer.py'), str(fmu),
                          str(tmp_path / 'inputs.npz'), str(tmp_path / 'out.npz')],
                         cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    return json.loads(out.stdout.strip().splitlines()[-1]), tmp_path / 'out.npz'


@pytest.mark.slow
@pytest.mark.parametrize('model', ['SQ', 'HD'])
def test_the_fmu_runs_outside_the_package_with_its_declared_packages(fmus, model, tmp_path):
    """In a Python with only FMPy and the packages the FMU declares (its requirements.txt),
    FMPy's validate_fmu finds nothing (InitialUnknowns declared) and the FMU gives simulate's
    run bit for bit: it carries the physics it needs."""
    import zipfile
    with zipfile.ZipFile(fmus / f'{model}.fmu') as z:
        req = z.read('resources/requirements.txt').decode().split()
    from servovalve_twin.fmu import REQUIRES
    assert [line.split('>=')[0] for line in req] == list(REQUIRES)
    from conftest import ROOT
    script = (ROOT / 'scripts' / 'fmu-venv').read_text()
    assert f'FMU_REQUIRES="{" ".join(REQUIRES)}"' in script     # the venv has just those
    r = simulate(model, PAPER, ecu_period=1e-3)
    result, out = _importer(fmus / f'{model}.fmu', r, tmp_path)
    assert result['problems'] == [] and result['error'] is None, result
    res = np.load(out)
    for k in ('xs', 'xj', 'dxj'):
        assert np.array_equal(res[k], r[k]), k
    held = np.concatenate([[True], r['psr'][1:] == r['psr'][:-1]])
    assert np.array_equal(res['p12'][held], r['p12'][held])


@pytest.mark.slow
def test_a_missing_package_is_named_in_the_fmu_log(fmus, tmp_path):
    """Without numba (hidden here by a module that refuses to import) the instantiation fails
    and the FMU's log names the packages and how to install them."""
    hide = tmp_path / 'hide'
    hide.mkdir()
    (hide / 'numba.py').write_text("raise ImportError(\"No module named 'numba'\")\n")
    r = simulate('SQ', {'duration': 0.01, 'com': [[0.0, 0.02]]}, ecu_period=1e-3)
    result, _ = _importer(fmus / 'SQ.fmu', r, tmp_path, extra_path=hide)
    assert result['error'] is not None
    text = '\n'.join(result['log'])
    print(text)
    assert 'needs the Python packages numpy and numba' in text and 'pythonfmu deploy' in text
