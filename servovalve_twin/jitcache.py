"""``jit``: numba's ``njit(cache=True)`` with a cache that is invalidated by a change in any
source the function may compile, not only in the function's own file.

Why. numba keys a cached function on its own source file's modification time and size: the step
loops in ``physics/plant.py`` inline the valve models of ``physics/valves/*.py``, the ECU, the
servovalve and the jack, and the monitor's tick (``prognostics/monitor_loop.py``) calls the
plant's; after an edit (or an upgrade) of one of those, numba would load the old machine code --
silently wrong results. Here each cached function carries a stamp of its own,
:func:`source_stamp`: a digest of the contents of its module and of every module of its package
that module imports, directly or through others (a compiled function can reach no other code: a
global it calls or a constant it freezes in comes from an import), whichever folder they are in.
Any change recompiles the functions that can see it, once, and the next processes load from the
cache again (bench/README.md: first-ever and warm start-up).

Where the cache lives is numba's choice (``__pycache__`` next to the source when writable,
else the user-wide cache directory; ``NUMBA_CACHE_DIR`` overrides both).
"""

from __future__ import annotations

import ast
import functools
import hashlib
import importlib
import os
from pathlib import Path

_PHYSICS_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'physics')
_THIS_FILE = os.path.abspath(__file__)
#: the sources outside physics/ the ahead-of-time module is made from (the monitor's loop,
#: which calls the physics' tick, and the builder, which states every loop's signature): in its
#: stamp, so that an edit of them renames it
AOT_SOURCES = tuple(os.path.join(os.path.dirname(_THIS_FILE), *p)
                    for p in (('prognostics', 'monitor_loop.py'), ('aot.py',)))


@functools.lru_cache(maxsize=None)
def physics_stamp() -> bytes:
    """SHA-256 over the relative names and contents of every ``.py`` file under physics/, of
    the monitor's compiled loop (:data:`AOT_SOURCES`: the module compiles it too) and of this
    file (it holds the compile options: an edit of them must recompile too): the name of the
    ahead-of-time module of the step loops (:mod:`~servovalve_twin.aot`). The JIT's disk cache
    is keyed per function, :func:`source_stamp`."""
    h = hashlib.sha256()
    for path in (_THIS_FILE, *AOT_SOURCES):
        # (a copy that carries the physics alone -- the FMU's -- has no module to name)
        if os.path.isfile(path):
            with open(path, 'rb') as f:
                h.update(f.read())
    for root, dirs, files in os.walk(_PHYSICS_DIR):
        dirs[:] = sorted(d for d in dirs if d != '__pycache__')
        for name in sorted(f for f in files if f.endswith('.py')):
            path = os.path.join(root, name)
            h.update(os.path.relpath(path, _PHYSICS_DIR).encode())
            with open(path, 'rb') as f:
                h.update(f.read())
    return h.digest()


def _package_root(path: str) -> str | None:
    """The folder holding the top package of the module at ``path``, or None for a module
    outside any package."""
    folder = os.path.dirname(path)
    if not os.path.isfile(os.path.join(folder, '__init__.py')):
        return None
    while os.path.isfile(os.path.join(os.path.dirname(folder), '__init__.py')):
        folder = os.path.dirname(folder)
    return os.path.dirname(folder)


def _module_file(root: str, dotted: str) -> str | None:
    """The source of module ``dotted`` under ``root`` (``a/b.py`` or ``a/b/__init__.py``)."""
    base = os.path.join(root, *dotted.split('.'))
    for candidate in (base + '.py', os.path.join(base, '__init__.py')):
        if os.path.isfile(candidate):
            return candidate
    return None


def _imported_files(path: str, root: str, top: str) -> set[str]:
    """The sources under ``root`` of package ``top`` that the module at ``path`` imports
    (absolute or relative; a ``from X import name`` counts X and, where ``name`` is a
    submodule, that submodule). The packages a module lies in count too: importing it runs
    their ``__init__``."""
    rel = os.path.relpath(path, root)[:-len('.py')].split(os.sep)
    if rel[-1] == '__init__':
        rel = rel[:-1]
        package = rel
    else:
        package = rel[:-1]
    with open(path, 'rb') as f:
        tree = ast.parse(f.read(), path)
    names = ['.'.join(package[:i]) for i in range(1, len(package) + 1)]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[:len(package) - node.level + 1]
                dotted = '.'.join(base + ([node.module] if node.module else []))
            else:
                dotted = node.module or ''
            names.append(dotted)
            names += [f'{dotted}.{a.name}' for a in node.names if a.name != '*']
    found = set()
    for dotted in names:
        if dotted.split('.')[0] != top:
            continue
        parts = dotted.split('.')
        for i in range(1, len(parts) + 1):      # every package on the way is imported too
            f = _module_file(root, '.'.join(parts[:i]))
            if f is not None:
                found.add(f)
    return found


@functools.lru_cache(maxsize=None)
def source_stamp(path: str) -> bytes:
    """SHA-256 over the contents of the module at ``path``, of every module of its package it
    imports, transitively (:func:`_imported_files`), and of this file (it holds the compile
    options: an edit of them must recompile too). Each file is named by its path relative to
    the package root, so a copy of the package elsewhere keeps the stamp."""
    path = os.path.abspath(path)
    root = _package_root(path)
    seen = {path}
    if root is not None:
        top = os.path.relpath(path, root).split(os.sep)[0]
        todo = [path]
        while todo:
            for f in _imported_files(todo.pop(), root, top):
                if f not in seen:
                    seen.add(f)
                    todo.append(f)
    h = hashlib.sha256()
    with open(_THIS_FILE, 'rb') as f:
        h.update(f.read())
    base = root or os.path.dirname(path)
    for name in sorted(os.path.relpath(f, base) for f in seen):
        h.update(name.encode() + b'\0')
        with open(os.path.join(base, name), 'rb') as f:
            h.update(hashlib.sha256(f.read()).digest())
    return h.digest()


@functools.lru_cache(maxsize=None)
def _stamped_cache_class():
    """numba's function cache keyed on :func:`source_stamp` of the function's module, or None
    where this numba's cache classes (internal API) are not where they were: ``cache=True``
    then."""
    try:
        from numba.core.caching import CompileResultCacheImpl, FunctionCache
    except ImportError:          # pragma: no cover - depends on the numba version
        return None

    class _StampedCacheImpl(CompileResultCacheImpl):
        def __init__(self, py_func):
            super().__init__(py_func)       # RuntimeError where the source file is gone
            stamp = source_stamp(py_func.__code__.co_filename)
            self._locator.get_source_stamp = lambda: stamp

    class _StampedCache(FunctionCache):
        _impl_class = _StampedCacheImpl

    return _StampedCache


def _dispatcher(f, options):
    """``njit(**options)(f)`` whose disk cache carries the function's source stamp."""
    from numba import njit
    dispatcher = njit(**options)(f)
    cache = _stamped_cache_class()
    try:
        if cache is None:
            dispatcher.enable_caching()
        else:
            # what cache=True does (Dispatcher.enable_caching), with the function's stamp
            dispatcher._cache = cache(dispatcher.py_func)
    except (RuntimeError, OSError):
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
    """``@jit`` or ``@jit(inline='always')``: ``njit`` cached on disk under its source stamp,
    made on first use (:class:`LazyJit`)."""
    def wrap(f):
        return LazyJit(f, options)
    return wrap if fn is None else wrap(fn)


# -- the step loops compiled ahead of time (servovalve_twin.aot builds them): the loader ------

#: where the module is built and looked for: beside this file (an editable install's source
#: tree, or site-packages)
PACKAGE_DIR = Path(__file__).resolve().parent
PREFIX = '_aot_loops_'


def _stamped() -> str:
    """The start of the names of the modules of the physics as they are now (any processor)."""
    return PREFIX + physics_stamp().hex()[:16]


def module_name() -> str:
    """The module's name for the physics as they are now, on this processor."""
    tag = cpu_tag()
    return _stamped() + (f'_{tag}' if tag else '')


@functools.lru_cache(maxsize=None)
def cpu_tag() -> str:
    """The processor the loops are compiled for, as a short digest of its vendor, family,
    model and feature flags (the first processor of ``/proc/cpuinfo``, read in < 1 ms), or ''
    where that cannot be read.

    Why. Compiled for the generic x86-64 the JIT's loops are not (numba's JIT targets the
    host), HD's loop ran 7 % and SQ's 11 % slower than the JIT's (interleaved, one process);
    compiled for the host they run alike. A module built for one processor may use
    instructions another lacks (a shared install, a copied image): its name carries this tag,
    so on another processor it is not found and the JIT serves. Without a tag, the generic
    target."""
    try:
        with open('/proc/cpuinfo', 'rb') as fh:
            first = fh.read(1 << 16).split(b'\n\n', 1)[0]
    except OSError:
        return ''
    keys = (b'vendor_id', b'cpu family', b'model', b'flags')
    lines = [ln for ln in first.splitlines() if ln.startswith(keys)]
    if not any(ln.startswith(b'flags') for ln in lines):
        return ''
    import zlib
    return '%08x' % zlib.crc32(b'\n'.join(lines))


def export_name(kind: str, model_id: int, sensed: bool = False) -> str:
    return f'run_{kind}_m{model_id}' + ('_sensed' if sensed else '')


@functools.lru_cache(maxsize=None)
def _module():
    """The compiled module of the current physics, or None (not built, stale, or the JIT
    asked for)."""
    if os.environ.get('SERVOVALVE_TWIN_JIT'):
        return None
    try:
        return importlib.import_module(f'{__package__}.{module_name()}')
    except ImportError:
        return None


def aot_loop(kind: str, model_id: int, sensed: bool = False):
    """The compiled loop (``kind`` 'steps' or 'fleet') of a valve model, or None where the JIT
    must serve."""
    mod = _module()
    return None if mod is None else getattr(mod, export_name(kind, model_id, sensed), None)
