"""package.xml as rosdep reads it: every dependency a ROS package of Jazzy or a rosdep key that
resolves -- ros/rosdistro's (a pinned excerpt, test/data/rosdep_keys.yaml) or this repository's
own rosdep source for the PyPI-only packages (rosdep/servovalve_twin.yaml) -- and every package
the code and the suite need declared."""

import re
import xml.etree.ElementTree as ET

import yaml

from conftest import ROOT

PINNED = yaml.safe_load((ROOT / 'test' / 'data' / 'rosdep_keys.yaml').read_text())
OWN = yaml.safe_load((ROOT / 'rosdep' / 'servovalve_twin.yaml').read_text())


def _depends():
    root = ET.parse(ROOT / 'package.xml').getroot()
    return {(el.tag, el.text.strip()) for el in root
            if el.tag.endswith('depend') and el.text}


def _pip_packages(rule) -> list[str]:
    return list((rule.get('pip') or {}).get('packages') or []) if isinstance(rule, dict) else []


def test_every_key_resolves_on_debian_and_ubuntu():
    """rosdep could not resolve six keys (python3-mcap, -zstandard, -lz4, -pyarrow, -dask,
    -rosbags): rosdistro has none of them. Each key is now a Jazzy package, an upstream key
    with a Debian and an Ubuntu rule, or a key of the repository's own source with a pip rule."""
    unresolved = []
    for _, key in _depends():
        if key in PINNED['jazzy_packages']:
            continue
        entry = PINNED['rosdep'].get(key) or OWN.get(key)
        if not entry or not all(entry.get(os_) for os_ in ('debian', 'ubuntu')):
            unresolved.append(key)
    assert not unresolved


def test_the_own_rosdep_source_adds_only_what_rosdistro_lacks():
    """A key of rosdep/servovalve_twin.yaml is a pip rule of a package requirements.txt lists,
    and not one rosdistro has (it would shadow the upstream rule)."""
    reqs = {re.split(r'[<>=\[ ]', line.strip())[0].lower()
            for line in (ROOT / 'requirements.txt').read_text().splitlines()
            if line.strip() and not line.startswith('#')}
    for key, entry in OWN.items():
        assert key not in PINNED['rosdep'] and key.endswith('-pip'), key
        for os_ in ('debian', 'ubuntu'):
            pkgs = _pip_packages(entry[os_])
            assert pkgs and all(re.split(r'[\[]', p)[0].lower() in reqs for p in pkgs), key


def test_every_package_the_code_and_the_suite_need_is_declared():
    """The PyPI packages of setup.py's install_requires are exec depends, those of the 'test'
    extra (what the suite needs: mcap-ros2-support, progpy, pythonfmu, fmpy were not declared)
    test depends -- each through the key whose rule installs it."""
    import ast
    tree = ast.parse((ROOT / 'setup.py').read_text())
    call = next(n for n in ast.walk(tree) if isinstance(n, ast.Call)
                and getattr(n.func, 'id', '') == 'setup')
    kw = {k.arg: ast.literal_eval(k.value) for k in call.keywords
          if k.arg in ('install_requires', 'extras_require')}
    provided: dict[str, set] = {'exec_depend': set(), 'test_depend': set()}
    for tag, key in _depends():
        entry = PINNED['rosdep'].get(key) or OWN.get(key) or {}
        rule = entry.get('debian')
        names = _pip_packages(rule) or ([key.removeprefix('python3-')] if rule else [])
        for name in names:
            provided.setdefault(tag, set()).add(re.split(r'[\[]', name)[0].lower())
    runtime = {re.split(r'[<>=\[]', r)[0].lower() for r in kw['install_requires']} - {
        'setuptools', 'pyyaml'} | {'yaml'}
    assert runtime <= provided['exec_depend'], runtime - provided['exec_depend']
    test = {re.split(r'[<>=\[]', r)[0].lower() for r in kw['extras_require']['test']}
    have = provided['exec_depend'] | provided['test_depend']
    assert test <= have, test - have
