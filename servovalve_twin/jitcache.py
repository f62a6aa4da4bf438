"""``jit``: numba's ``njit(cache=True)`` with a cache that is invalidated by a change anywhere in
the compiled physics, not only in the function's own file.

Why. numba keys a cached function on its own source file: the step loops in
``physics/plant.py`` inline the valve models of ``physics/valves/*.py``, the ECU, the servovalve
and the jack, and after an edit (or an upgrade) of one of those, numba would load the old
machine code for the loop -- silently wrong physics. Here every cached function of the physics
carries one stamp, a digest of all of ``physics/``'s sources, so any change recompiles them all
once and the next processes load from the cache again (bench/README.md: first-ever and warm
start-up).

Where the cache lives is numba's choice (``__pycache__`` next to the source when writable,
else the user-wide cache directory; ``NUMBA_CACHE_DIR`` overrides both).
"""

from __future__ import annotations

import functools
import hashlib
import os

_PHYSICS_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'physics')
_THIS_FILE = os.path.abspath(__file__)


@functools.lru_cache(maxsize=None)
def physics_stamp() -> bytes:
    """SHA-256 over the relative names and contents of every ``.py`` file under physics/, and
    of this file (it holds the compile options: an edit of them must recompile too)."""
    h = hashlib.sha256()
    with open(_THIS_FILE, 'rb') as f:
        h.update(f.read())
    for root, dirs, files in os.walk(_PHYSICS_DIR):
        dirs[:] = sorted(d for d in dirs if d != '__pycache__')
        for name in sorted(f for f in files if f.endswith('.py')):
            path = os.path.join(root, name)
            h.update(os.path.relpath(path, _PHYSICS_DIR).encode())
            with open(path, 'rb') as f:
                h.update(f.read())
    return h.digest()


@functools.lru_cache(maxsize=None)
def _physics_cache_class():
    """numba's function cache keyed on the physics stamp, or None where this numba's cache
    classes (internal API) are not where they were: ``cache=True`` then."""
    try:
        from numba.core.caching import CompileResultCacheImpl, FunctionCache
    except ImportError:          # pragma: no cover - depends on the numba version
        return None

    class _PhysicsCacheImpl(CompileResultCacheImpl):
        def __init__(self, py_func):
            super().__init__(py_func)
            stamp = physics_stamp()
            self._locator.get_source_stamp = lambda: stamp

    class _PhysicsCache(FunctionCache):
        _impl_class = _PhysicsCacheImpl

    return _PhysicsCache


def _dispatcher(f, options):
    """``njit(**options)(f)`` whose disk cache carries the physics stamp."""
    from numba import njit
    dispatcher = njit(**options)(f)
    cache = _physics_cache_class()
    try:
        if cache is None:
            dispatcher.enable_caching()
        else:
            # what cache=True does (Dispatcher.enable_caching), with the physics-wide stamp
            dispatcher._cache = cache(dispatcher.py_func)
    except RuntimeError:
        # no place to key a cache on: the source file is gone (an FMU's resources, deleted
        # by the importer after a run, while the module stays imported): compiled in memory
        pass
    return dispatcher


class LazyJit:
    """A compiled function whose numba dispatcher is made on first use, so that importing the
    physics does not import numba (~0.11 s of a process; the loops compiled ahead of time,
    :mod:`servovalve_twin.aot`, run without it).

    First use is a call from Python, any dispatcher attribute (``compile``, ``signatures``,
    ...), or numba compiling a function that calls this one: numba types a global or a closure
    variable by its ``_numba_type_`` (the dispatcher's type, so the call is compiled as a call of
    the dispatcher) and inlines an ``inline='always'`` callee from ``targetoptions`` and
    ``py_func`` -- the attributes it reads from a dispatcher, here without making one.
    """

    def __init__(self, f, options):
        self.py_func = f
        self.targetoptions = dict(options)
        self._dispatcher = None
        functools.update_wrapper(self, f)

    @property
    def dispatcher(self):
        if self._dispatcher is None:
            self._dispatcher = _dispatcher(self.py_func, self.targetoptions)
        return self._dispatcher

    @property
    def _numba_type_(self):
        return self.dispatcher._numba_type_

    def __call__(self, *args, **kwargs):
        return self.dispatcher(*args, **kwargs)

    def __getattr__(self, name):
        # only for names this class does not have: the dispatcher's own (compile, overloads, ..)
        if name.startswith('__') or name == '_dispatcher':
            raise AttributeError(name)
        return getattr(self.dispatcher, name)

    def __repr__(self):
        return f'<LazyJit {self.py_func.__qualname__}>'


def jit(fn=None, **options):
    """``@jit`` or ``@jit(inline='always')``: ``njit`` cached on disk under the physics stamp,
    made on first use (:class:`LazyJit`)."""
    def wrap(f):
        return LazyJit(f, options)
    return wrap if fn is None else wrap(fn)
