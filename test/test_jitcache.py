"""servovalve_twin.jitcache: compiled functions made on first use, so that importing the
physics imports no numba, compiled as numba's own dispatchers would be."""

import importlib
import subprocess
import sys

import numpy as np

from servovalve_twin.jitcache import LazyJit


def test_importing_the_physics_and_the_commands_imports_no_numba():
    """The physics, simulate(), the fleet and the CLI import without numba (the compiled
    loops run without it): a decorator that made its dispatcher at import would import it."""
    script = ('import sys, servovalve_twin.runs, servovalve_twin.physics.fleet, '
              'servovalve_twin.physics.simulate, servovalve_twin.cli, '
              'servovalve_twin.prognostics.monitor_loop; '
              'print(sorted(m for m in sys.modules if m.split(".")[0] == "numba"))')
    out = subprocess.run([sys.executable, '-c', script], capture_output=True, text=True,
                         check=True).stdout
    assert out.strip() == '[]'


LAZY_SOURCE = """
from servovalve_twin.jitcache import jit

@jit(inline='always')
def half(x):
    return 0.5 * x

@jit
def square(x):
    return x * x

@jit
def sum_of(xs):
    acc = 0.0
    for x in xs:
        acc += square(half(x))
    return acc
"""


def _import_from(directory, name, source):
    """``source`` as module ``name`` from a file in ``directory`` (a fresh file: numba's disk
    cache, keyed on it, starts empty)."""
    (directory / f'{name}.py').write_text(source)
    sys.path.insert(0, str(directory))
    try:
        return importlib.import_module(name)
    finally:
        sys.path.remove(str(directory))


def test_lazy_functions_compile_and_call_each_other_as_dispatchers(tmp_path):
    """A lazy function calling two others (one ``inline='always'``) compiles and gives the
    arithmetic's answer; the callee is compiled as a function of its own, the inlined one
    not (numba inlined its source: it must find ``inline`` in the lazy function's options)."""
    mod = _import_from(tmp_path, 'lazy_mod', LAZY_SOURCE)
    try:
        for f in (mod.half, mod.square, mod.sum_of):
            assert isinstance(f, LazyJit)
        assert mod.sum_of(np.array([2.0, -4.0, 6.0])) == 1.0 + 4.0 + 9.0
        assert mod.sum_of.signatures and mod.square.signatures
        assert not mod.half.signatures
        assert mod.half(3.0) == 1.5 and mod.half.signatures      # called from Python
    finally:
        del sys.modules['lazy_mod']


def test_a_function_whose_source_is_gone_compiles_in_memory(tmp_path):
    """A module imported from files deleted since (an FMU's resources, removed by the importer
    after a run, the module still imported) compiles without a disk cache instead of failing
    to find a place for one."""
    gone_mod = _import_from(tmp_path, 'gone_mod', 'from servovalve_twin.jitcache import jit'
                            '\n\n@jit\ndef twice(x):\n    return 2 * x\n')
    (tmp_path / 'gone_mod.py').unlink()
    try:
        assert gone_mod.twice(21) == 42
    finally:
        del sys.modules['gone_mod']
