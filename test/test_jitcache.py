"""servovalve_twin.jitcache: compiled functions made on first use, so that importing the
physics imports no numba, compiled as numba's own dispatchers would be."""

import importlib
import os
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


def _run_scratch(tmp_path, cache):
    """``scratchpkg.loop.tick.scaled(1.0)`` in a new process whose numba disk cache is
    ``cache``; returns the value and whether it was loaded from the cache."""
    script = ('import scratchpkg.loop.tick as t; v = t.scaled(1.0); '
              'print(v, t.scaled.dispatcher.stats.cache_hits.get(t.scaled.signatures[0], 0))')
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache),
               PYTHONPATH=os.pathsep.join([str(tmp_path), *sys.path]))
    out = subprocess.run([sys.executable, '-c', script], capture_output=True, text=True,
                         env=env, cwd=tmp_path, check=True).stdout.split()
    return float(out[0]), int(out[1]) > 0


def test_a_cached_function_sees_an_edit_of_any_module_it_imports(tmp_path):
    """A jitted function outside physics/ (as the monitor's tick is) freezes in a constant of
    its own module and calls a function of a sibling package: an edit of either -- same size,
    so that not even numba's own modification-time stamp would help where the clock is coarse
    -- is compiled anew in the next process with the same disk cache, never loaded stale;
    an unchanged package is loaded from the cache."""
    pkg = tmp_path / 'scratchpkg'
    (pkg / 'loop').mkdir(parents=True)
    (pkg / 'gains').mkdir()
    for d in (pkg, pkg / 'loop', pkg / 'gains'):
        (d / '__init__.py').write_text('')
    gain = pkg / 'gains' / 'law.py'
    gain.write_text('from servovalve_twin.jitcache import jit\n\nK = 3.0\n\n\n'
                    '@jit\ndef law(x):\n    return K * x\n')
    tick = pkg / 'loop' / 'tick.py'
    tick.write_text('from servovalve_twin.jitcache import jit\n\nfrom ..gains.law import law'
                    '\n\nOFFSET = 1.0\n\n\n@jit\ndef scaled(x):\n    return law(x) + OFFSET\n')
    cache = tmp_path / 'cache'
    assert _run_scratch(tmp_path, cache) == (4.0, False)
    assert _run_scratch(tmp_path, cache) == (4.0, True)
    tick.write_text(tick.read_text().replace('OFFSET = 1.0', 'OFFSET = 2.0'))
    assert _run_scratch(tmp_path, cache) == (5.0, False)
    gain.write_text(gain.read_text().replace('K = 3.0', 'K = 5.0'))
    assert _run_scratch(tmp_path, cache) == (7.0, False)
    assert _run_scratch(tmp_path, cache) == (7.0, True)


def test_the_monitor_tick_stamp_covers_the_physics_it_calls(tmp_path):
    """The monitor's tick (prognostics/) is stamped with its own module and the physics it
    calls: an edit of monitor_loop.py or of a valve model changes its stamp; an edit of a
    module it does not import (the CLI) does not."""
    import shutil

    from servovalve_twin import jitcache
    src = os.path.dirname(jitcache.__file__)
    copy = tmp_path / 'servovalve_twin'
    shutil.copytree(src, copy, ignore=shutil.ignore_patterns('__pycache__', '*.so', 'data'))
    loop = str(copy / 'prognostics' / 'monitor_loop.py')

    def stamp():
        jitcache.source_stamp.cache_clear()
        return jitcache.source_stamp(loop)

    before = stamp()
    for edited, changes in (('cli/__main__.py', False), ('prognostics/monitor_loop.py', True),
                            ('physics/valves/hd.py', True), ('physics/plant.py', True)):
        f = copy / edited
        f.write_text(f.read_text() + '\n# edited\n')
        after = stamp()
        assert (after != before) == changes, edited
        before = after
    jitcache.source_stamp.cache_clear()
