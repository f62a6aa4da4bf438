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

from numba import njit

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


try:        # numba's cache classes: internal API, so a numba that renames them still works
    from numba.core.caching import CompileResultCacheImpl, FunctionCache

    class _PhysicsCacheImpl(CompileResultCacheImpl):
        def __init__(self, py_func):
            super().__init__(py_func)
            stamp = physics_stamp()
            self._locator.get_source_stamp = lambda: stamp

    class _PhysicsCache(FunctionCache):
        _impl_class = _PhysicsCacheImpl

except ImportError:          # pragma: no cover - depends on the numba version
    _PhysicsCache = None


def jit(fn=None, **options):
    """``@jit`` or ``@jit(inline='always')``: ``njit`` cached on disk under the physics stamp."""
    def wrap(f):
        if _PhysicsCache is None:
            return njit(cache=True, **options)(f)
        dispatcher = njit(**options)(f)
        # what cache=True does (Dispatcher.enable_caching), with the physics-wide stamp
        dispatcher._cache = _PhysicsCache(dispatcher.py_func)
        return dispatcher
    return wrap if fn is None else wrap(fn)
