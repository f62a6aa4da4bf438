"""The step loops compiled ahead of time: ``python -m servovalve_twin.aot`` (``scripts/setup``
runs it after installing) builds one extension module holding every valve model's loops
(:func:`~.physics.plant.run_steps_for`, without and with sensors, and the fleet's
:func:`~.physics.fleet.run_fleet_for`) with numba's ahead-of-time compiler and gcc, so that a
process runs a loop without compiling it or loading numba's cache. A plain ``pip install .``
or a ``colcon build`` builds the module too (setup.py's ``build_py``; pyproject.toml brings
numba into pip's build); an editable install does not (``scripts/setup`` runs this module
after it) -- without the module each model's loops are compiled by the first process that
runs them (2-5 s) and loaded from numba's disk cache by the next ones. ``--check`` says whether
the module of the current physics is there.

This module is the builder; the loader the physics uses (:func:`~.jitcache.aot_loop`) is in
:mod:`~.jitcache`, below the physics (the physics imported it from here: a circle). The module is
named after the physics stamp (:func:`~.jitcache.physics_stamp`, a digest of every
source of the compiled physics): after any edit of the physics its name no longer matches, it
is not loaded, and the loops come from the JIT again -- which stays the fallback (a machine
without the module, an editable install after a physics edit, the FMU) and the reference:
the same Python source compiled by the same numba, and a test holds the two to the same bytes.
``SERVOVALVE_TWIN_JIT=1`` in the environment uses the JIT even where the module exists.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .jitcache import (PACKAGE_DIR, PREFIX, _module, _stamped, aot_loop, cpu_tag,  # noqa: F401
                       export_name, module_name)

#: the loops compiled: (kind, sensor variants). 'tick': one control period of the ROS plant
#: (:func:`~.physics.plant.run_tick`); 'monitor': the monitor's rows
#: (:func:`~.prognostics.monitor_loop.monitor_rows`) -- without them a standalone plant or
#: monitor node compiled (or loaded numba) after saying it had started, and the first
#: ``run --monitor SQ`` compiled for ~7.5 s
KINDS = {'steps': (False, True), 'fleet': (False,), 'tick': (False,), 'monitor': (False,)}


def loop_signature(kind: str, model_id: int, sensed: bool = False):
    """The numba signature of a model's loop: the types of the arguments
    :func:`~.physics.simulate.simulate` (``kind`` 'steps') or
    :func:`~.physics.fleet.simulate_many` ('fleet') pass, built here as they build them."""
    import numpy as np
    from numba import typeof

    from .physics.params import DEFAULTS
    from .physics.plant import OUT_COLUMNS, TRUTH_COLUMNS
    from .physics.sensors import SENSED, sensor_table
    from .physics.servovalve import S_SIZE
    from .physics.valves import VALVE_MODELS
    model = next(m for m in VALVE_MODELS.values() if m.id == model_id)
    inputs = np.zeros((3, 8))[:, :4]            # simulate's input rows: views of one buffer
    kern = np.concatenate([model.kernel_array(DEFAULTS)])
    if kind == 'tick':
        args = (0, np.zeros(S_SIZE), model.initial_state(DEFAULTS), kern, 0.0, 0.0, 0.0, 0,
                np.zeros(4))
        return typeof(0)(*(typeof(a) for a in args))
    if kind == 'monitor':
        from .prognostics.monitor_loop import OUT_COLUMNS as MON_OUT
        from .prognostics.monitor_loop import U_COLUMNS, W_SIZE
        args = (0, np.zeros(S_SIZE), model.initial_state(DEFAULTS), kern, 0,
                np.zeros((2, len(U_COLUMNS))), np.zeros(W_SIZE), np.zeros((3, 2)),
                np.zeros((2, len(MON_OUT))), np.zeros(2, dtype=np.int8), False)
        return typeof(0)(*(typeof(a) for a in args))
    if kind == 'fleet':
        args = (np.zeros((2, S_SIZE)), np.stack([model.initial_state(DEFAULTS)] * 2),
                np.empty((2, 1), dtype=kern.dtype), np.zeros((2, 1), dtype=np.int64),
                inputs[0], inputs[1], inputs[2], 0, 0, 0, 0, np.zeros((2, 2)),
                np.zeros((2, 2, len(OUT_COLUMNS))), 1e-3, np.zeros(2, dtype=np.int64))
        return typeof(0)(*(typeof(a) for a in args))
    spec, keys = sensor_table(None, 1, DEFAULTS.DT)
    args = (np.zeros(S_SIZE), model.initial_state(DEFAULTS),
            kern, np.zeros(1, dtype=np.int64),
            inputs[0], inputs[1], inputs[2], 0, 0, 0, 0, np.zeros(2),
            np.zeros((2, len(OUT_COLUMNS) + (len(TRUTH_COLUMNS) if sensed else 0))), 1e-3,
            spec, keys, np.zeros(len(SENSED)), 0)
    return typeof(0)(*(typeof(a) for a in args))


def build(dest: Path = PACKAGE_DIR, model_ids=None) -> Path:
    """Compile the loops of ``model_ids`` (default every registered model) -- each kind of
    :data:`KINDS`, in each variant -- into ``dest/<module_name()>``; earlier modules of this
    builder there (other stamps) are removed. Returns the module's path."""
    import warnings

    from .physics.fleet import jit_run_fleet_for
    from .physics.plant import jit_run_steps_for, run_tick
    from .prognostics.monitor_loop import monitor_rows
    from .physics.valves import MONITOR_MODEL_NAMES, VALVE_MODELS
    ids = sorted(m.id for m in VALVE_MODELS.values()) if model_ids is None else model_ids
    with warnings.catch_warnings():
        # numba.pycc is marked for deprecation (since 0.57, still there in 0.68): used while it
        # exists, the JIT serving where it does not
        warnings.simplefilter('ignore')
        from numba.pycc import CC
    cc = CC(module_name())
    cc.output_dir = str(dest)
    cc.verbose = False
    if cpu_tag():
        cc.target_cpu = 'host'          # the processor the name's tag stands for
    jit = {'steps': jit_run_steps_for, 'fleet': lambda mid, sensed: jit_run_fleet_for(mid),
           'tick': lambda mid, sensed: run_tick, 'monitor': lambda mid, sensed: monitor_rows}
    monitors = {m.id for m in VALVE_MODELS.values() if m.name in MONITOR_MODEL_NAMES}
    for mid in ids:
        for kind, variants in KINDS.items():
            if kind == 'monitor' and mid not in monitors:
                continue                    # (HD is no monitor model)
            for sensed in variants:
                cc.export(export_name(kind, mid, sensed), loop_signature(kind, mid, sensed))(
                    jit[kind](mid, sensed).py_func)
    cc.compile()
    built = next(dest.glob(module_name() + '.*'))
    for old in dest.glob(PREFIX + '*'):
        if not old.name.startswith(_stamped()):  # other processors' modules of it stay
            old.unlink()
    _module.cache_clear()
    return built


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog='python -m servovalve_twin.aot', description=__doc__.split(
        '\n\n')[0])
    ap.add_argument('--dest', type=Path, default=PACKAGE_DIR,
                    help='the directory of the module (default the package)')
    ap.add_argument('--if-missing', action='store_true',
                    help='build only if the module of the current physics is not there')
    ap.add_argument('--check', action='store_true',
                    help='build nothing: exit 0 if the module of the current physics is '
                         'there, 1 if not')
    args = ap.parse_args(argv)
    there = any(args.dest.glob(module_name() + '.*'))
    if args.check:
        return 0 if there else 1
    if args.if_missing and there:
        return 0
    path = build(args.dest)
    print(f'compiled the step loops into {path}', file=sys.stderr)
    return 0


if __name__ == '__main__':
    sys.exit(main())
