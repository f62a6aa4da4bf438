"""``servovalve-twin fmu``: an FMI 2.0 co-simulation FMU of the EHA, built with pythonfmu from
:mod:`.slave` (the model), a resource naming the valve model and control period, and the
physics it runs: the FMU carries its own copy of ``servovalve_twin.physics`` (and the two small
modules it imports), so the importing tool's Python needs only the packages listed in
:data:`REQUIRES` -- written into the FMU as ``resources/requirements.txt`` (``pythonfmu deploy
-f EHA.fmu`` installs them) and into its description. pythonfmu embeds itself."""

from __future__ import annotations

import json
import os
import shutil
import sys
import tempfile
from pathlib import Path
from typing import Any, Mapping

from ..errors import TwinError
from ..outputs import place_new, write_failed
from ..physics.params import DEFAULTS
from ..physics.sensors import sensors_from_dict
from ..physics.simulate import steps_per
from ..physics.valves import get_valve_model

#: the module name the slave has inside the FMU (pythonfmu imports it by this name)
SLAVE_MODULE = 'servovalve_twin_eha'
#: what the importing tool's Python must have (the physics is numpy and numba-compiled loops)
REQUIRES = ('numpy', 'numba')
#: the package files the slave's physics imports (physics/ whole; checked by a test);
#: jitcache.py's loader finds no compiled module inside the FMU, so its loops come from the JIT
CARRIED = ('__init__.py', 'errors.py', 'jitcache.py', 'physics')
#: the name the carried copy has inside the FMU: not ``servovalve_twin``, which it would shadow
#: in the importing process (pythonfmu puts the FMU's resources first on ``sys.path``; a
#: process that loaded the FMU then failed to import ``servovalve_twin.prognostics`` -- a Dask
#: worker spawned from it did)
CARRIED_AS = '_servovalve_twin_fmu'
#: the FMU's resource naming the valve model and control period it was built for
CONFIG = 'eha_fmu.json'


def _requirements() -> str:
    """``resources/requirements.txt``: each required package at least at the version this FMU
    was built and tested with."""
    from importlib.metadata import version
    lines = []
    for name in REQUIRES:
        major, minor = version(name).split('.')[:2]
        lines.append(f'{name}>={major}.{minor}')
    return '\n'.join(lines) + '\n'


def _carry_package(dest: Path) -> Path:
    """A copy of the package's physics (sources only) at ``dest/<CARRIED_AS>``."""
    src = Path(__file__).resolve().parents[1]
    pkg = dest / CARRIED_AS
    pkg.mkdir()
    for name in CARRIED:
        if (src / name).is_dir():
            shutil.copytree(src / name, pkg / name,
                            ignore=shutil.ignore_patterns('__pycache__', '*.pyc'))
        else:
            shutil.copyfile(src / name, pkg / name)
    return pkg


def build_fmu(valve_model: str, out: str | Path, *, control_period: float = 1e-3,
              sensors: Mapping[str, Any] | None = None) -> Path:
    """Write ``out`` (.fmu): the EHA with ``valve_model``, its ECU sampled every
    ``control_period``, measured by ``sensors`` (a mapping of the scenario's ``sensors``
    schema; None: ideal). Refuses an existing ``out`` (it overwrites nothing)."""
    model = get_valve_model(valve_model)
    n_sub = steps_per(control_period, DEFAULTS, '--control-period')
    sens = sensors_from_dict(sensors, 'sensors')
    if sens:
        sens.table(n_sub, DEFAULTS.DT)          # the periods checked now, not in the importer
    out = Path(out)
    if out.suffix != '.fmu':
        raise TwinError(f'{out}: the FMU file must end in .fmu')
    if out.exists():
        raise TwinError(f'{out} exists; give a new file name (nothing is overwritten)')
    if not out.parent.is_dir():
        raise TwinError(f'{out.parent} is not a directory')
    try:
        _build(out, model, control_period, sens)
    except (OSError, shutil.Error) as exc:
        # the build's temporary directory is not the user's business: say where and why
        # (shutil.Error listed every file of the carried package under /tmp/svt_fmu_...)
        cause = exc
        if isinstance(exc, shutil.Error):
            import re
            found = re.search(r'\[Errno (\d+)\]', str(exc))
            code = int(found.group(1)) if found else 0
            cause = OSError(code, os.strerror(code) if code else 'a file could not be copied')
        raise write_failed(out, cause, f'the FMU is built in {tempfile.gettempdir()} (TMPDIR) '
                           'first; nothing of it was written') from None
    return out


def _build(out: Path, model, control_period: float, sens) -> None:
    """The FMU built in a temporary directory and moved to ``out`` (:func:`build_fmu`)."""
    from pythonfmu.builder import FmuBuilder
    with tempfile.TemporaryDirectory(prefix='svt_fmu_') as tmp:
        tmp = Path(tmp)
        script = tmp / f'{SLAVE_MODULE}.py'
        shutil.copyfile(Path(__file__).with_name('slave.py'), script)
        cfg = tmp / CONFIG
        cfg.write_text(json.dumps(dict(valve_model=model.name,
                                       control_period=float(control_period),
                                       sensors=sens.to_dict() if sens else None)))
        req = tmp / 'requirements.txt'
        req.write_text(_requirements())
        carried = _carry_package(tmp)
        # built beside the target, then moved into place: a failed build leaves no file
        before = set(sys.modules)
        try:
            built = FmuBuilder.build_FMU(script, dest=tmp / out.name,
                                         project_files=[cfg, req, carried])
        finally:
            # the builder imports the slave, and with it the carried copy, from this temporary
            # directory: forgotten here, so that an FMU run later in this process imports its
            # own resources, not files that are about to be deleted (numba would find no
            # source to key its cache on)
            for name in set(sys.modules) - before:
                if name == SLAVE_MODULE or name.split('.')[0] == CARRIED_AS:
                    del sys.modules[name]
        place_new(built, out)


__all__ = ['build_fmu', 'SLAVE_MODULE', 'REQUIRES', 'CARRIED_AS', 'CONFIG']
