"""Parameters: defaults, bounds, coercion of YAML 1.1 strings, config/eha.yaml."""

import math

import pytest
import yaml

from servovalve_twin.errors import ParameterError
from servovalve_twin.physics.params import (DEFAULTS, PARAM_NAMES, EhaParams, coerce,
                                            make_params, parse_assignments, param_table)
from conftest import ROOT


def test_config_file_equals_dataclass_defaults():
    raw = yaml.safe_load((ROOT / 'config' / 'eha.yaml').read_text())['/**']['ros__parameters']
    for name, value in raw.items():
        assert name in PARAM_NAMES, name
        assert DEFAULTS.value(name) == value, name
        # ROS rejects an integer literal for a double parameter: every float must be a float
        if PARAM_TABLE[name]['kind'] == 'float':
            assert isinstance(value, float), f'{name} is written as {type(value).__name__}'
    missing = {r['name'] for r in param_table() if not r['derived']} - set(raw)
    assert not missing


PARAM_TABLE = {r['name']: r for r in param_table()}


def test_derived_values():
    assert DEFAULTS.gm == pytest.approx(1000.0 * 1.5e-4 / 0.01)     # 15 N/A
    assert DEFAULTS.v0 == pytest.approx(7.05e-4 * 0.1 + 2e-5)
    assert DEFAULTS.k == pytest.approx(0.2068, rel=1e-3)
    assert DEFAULTS.c4_alpha == pytest.approx(1 / (1 + DEFAULTS.k))
    assert DEFAULTS.replace(GM=7.5).gm == 7.5        # a given value overrides the derivation
    assert DEFAULTS.dt_ns == 10_000


@pytest.mark.parametrize('name,value,fragment', [
    ('M', -1.0, 'M = -1.0 kg is out of range'),
    ('M', math.nan, 'must be finite'),
    ('DT', 0.0, 'out of range'),
    ('CLk', math.inf, 'must be finite'),
    ('c', 0.0, 'allowed (0'),
    ('FDJ', 400.0, 'must not exceed the static friction'),
    ('DT', 1.00000001e-5, 'whole number of nanoseconds'),
    ('C4_alpha', 1.9, 'below 2/(1+k)'),
    ('C4_max_iter', 2.5, 'must be an integer'),
    ('compressible', 'maybe', 'true or false'),
    ('Mass', 1.0, "unknown parameter 'Mass'"),
])
def test_bad_values_rejected_with_name(name, value, fragment):
    with pytest.raises(ParameterError, match=None) as err:
        make_params({name: value})
    print(err.value)
    assert fragment in str(err.value)


def test_yaml11_strings_become_numbers():
    # PyYAML reads 20.0e6 and 2e-13 as strings: they must arrive as numbers or be rejected
    raw = yaml.safe_load('a: 20.0e6\nb: 2e-13\n')
    assert isinstance(raw['a'], str)
    p = make_params({'PSRN': raw['a'], 'CLk': raw['b']})
    assert p.PSRN == 20.0e6 and p.CLk == 2e-13
    with pytest.raises(ParameterError, match='must be a number'):
        coerce('M', 'heavy')


def test_cli_assignments():
    assert parse_assignments(['M=400', 'compressible=true']) == {'M': 400.0,
                                                                  'compressible': True}
    with pytest.raises(ParameterError, match='NAME=VALUE'):
        parse_assignments(['M'])


def test_frozen():
    import dataclasses
    with pytest.raises(dataclasses.FrozenInstanceError):
        DEFAULTS.M = 1.0  # type: ignore[misc]
    assert isinstance(DEFAULTS, EhaParams)


def test_every_documented_name_exists():
    for name in ('AJ', 'M', 'CJ', 'FDJ', 'FSJ', 'CLk', 'XSM', 'XSS', 'GPQ', 'GAP', 'CorM', 'w',
                 'c', 'r', 'L_S1', 'L_1R', 'L_S2', 'L_2R', 'Cd', 'rho', 'mu', 'PR', 'DT'):
        assert name in PARAM_NAMES


def test_the_reference_docs_list_every_parameter_and_fault():
    """doc/reference/tables.md renders the parameter and fault tables from the code's own
    tables (doc/_ext/twin_tables.py), never from a hand-kept copy: every name is a row."""
    import importlib.util
    from servovalve_twin.physics.faults import FAULTS
    spec = importlib.util.spec_from_file_location('twin_tables',
                                                  ROOT / 'doc' / '_ext' / 'twin_tables.py')
    tables = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tables)
    assert [r[0] for r in tables.TABLES['params']()[1]] == list(PARAM_NAMES)
    assert [r[0] for r in tables.TABLES['faults']()[1]] == list(FAULTS)
    page = (ROOT / 'doc' / 'reference' / 'tables.md').read_text()
    for name in tables.TABLES:
        assert f'```{{twin-table}} {name}' in page


def test_kernel_array_is_a_fresh_copy_of_the_kernel_each_call():
    """The kernel array is built once per parameter set and kept on it, yet every call hands
    out its own copy with the kernel's values; a cache keyed by equality would give the
    parameters CLk = -0.0 the kernel of CLk = 0.0 (equal, not the same bits)."""
    from servovalve_twin.physics.params import kernel_as_array
    p = EhaParams()
    a = p.kernel_array()
    assert a.tobytes() == kernel_as_array(p.kernel()).tobytes()
    a['CLk'] = 123.0                                  # the caller's copy only
    b = p.kernel_array((2.5,))
    assert b['VC0'][0] == 2.5 and b.tobytes() == kernel_as_array(p.kernel((2.5,))).tobytes()
    assert p.kernel_array()['CLk'][0] == p.CLk
    zero, neg = p.replace(CLk=0.0), p.replace(CLk=-0.0)
    assert neg == zero and math.copysign(1.0, zero.kernel_array()['CLk'][0]) == 1.0
    assert math.copysign(1.0, neg.kernel_array()['CLk'][0]) == -1.0


def test_replace_checks_what_it_changes_and_leaves_the_kernels_behind():
    """replace() re-checks only the changed fields and the cross checks: its result equals
    the instance built from scratch with every field checked, a bad change is refused, and
    the original's kernel arrays (kept on it) do not travel to the copy."""
    import dataclasses
    p = EhaParams()
    p.kernel_array()
    q = p.replace(M=400.0, CLk='2e-12')
    assert q == EhaParams(**{**{f.name: getattr(p, f.name) for f in dataclasses.fields(p)},
                             'M': 400.0, 'CLk': 2e-12})
    assert q.kernel_array()['M'][0] == 400.0 and q.kernel_array()['CLk'][0] == 2e-12
    assert p.kernel_array()['M'][0] == p.M
    with pytest.raises(ParameterError, match='must not exceed the static friction'):
        q.replace(FDJ=q.FSJ * 2)                       # a cross check on a changed field
    with pytest.raises(ParameterError, match='out of range'):
        q.replace(DT=0.0)


def test_derived_parameters_equal_to_their_derivation_derive_again():
    """A design given every parameter resolved (a bag's provenance records them so) pins the
    derived ones: a leak of 50 x CLk then kept C4_alpha at the healthy 1/(1+k), beyond the C4
    run's limit 2/(1+k), and was refused. derived_again leaves each one equal to its
    derivation to derive anew (C4_alpha = 1/(1+k) of the new k, by hand), and keeps one that
    was chosen."""
    from servovalve_twin.errors import ParameterError
    pinned = DEFAULTS.replace(**DEFAULTS.resolved())
    with pytest.raises(ParameterError, match='C4_alpha'):
        pinned.replace(CLk=DEFAULTS.CLk * 50)
    free = pinned.derived_again()
    assert all(getattr(free, n) is None for n in ('GM', 'V0', 'C4_alpha', 'XSS', 'GPQ'))
    leaky = free.replace(CLk=DEFAULTS.CLk * 50)
    assert leaky.c4_alpha == pytest.approx(1.0 / (1.0 + 50 * DEFAULTS.CLk * DEFAULTS.gpq))
    chosen = pinned.replace(C4_alpha=0.5).derived_again()
    assert chosen.C4_alpha == 0.5 and chosen.XSS is None

