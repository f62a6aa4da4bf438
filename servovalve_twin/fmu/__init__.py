"""``servovalve-twin fmu``: an FMI 2.0 co-simulation FMU of the EHA, built with pythonfmu from
:mod:`.slave` (the model) and a resource naming the valve model and control period."""

from __future__ import annotations

import json
import shutil
import tempfile
from pathlib import Path

from ..errors import TwinError
from ..physics.params import DEFAULTS
from ..physics.simulate import steps_per
from ..physics.valves import get_valve_model

#: the module name the slave has inside the FMU (pythonfmu imports it by this name)
SLAVE_MODULE = 'servovalve_twin_eha'


def build_fmu(valve_model: str, out: str | Path, *, control_period: float = 1e-3) -> Path:
    """Write ``out`` (.fmu): the EHA with ``valve_model``, its ECU sampled every
    ``control_period``. Refuses an existing ``out`` (it overwrites nothing)."""
    from pythonfmu.builder import FmuBuilder
    from .slave import CONFIG
    model = get_valve_model(valve_model)
    steps_per(control_period, DEFAULTS, '--control-period')
    out = Path(out)
    if out.suffix != '.fmu':
        raise TwinError(f'{out}: the FMU file must end in .fmu')
    if out.exists():
        raise TwinError(f'{out} exists; give a new file name (nothing is overwritten)')
    if not out.parent.is_dir():
        raise TwinError(f'{out.parent} is not a directory')
    with tempfile.TemporaryDirectory(prefix='svt_fmu_') as tmp:
        tmp = Path(tmp)
        script = tmp / f'{SLAVE_MODULE}.py'
        shutil.copyfile(Path(__file__).with_name('slave.py'), script)
        cfg = tmp / CONFIG
        cfg.write_text(json.dumps(dict(valve_model=model.name,
                                       control_period=float(control_period))))
        # built beside the target, then moved into place: a failed build leaves no file
        built = FmuBuilder.build_FMU(script, dest=tmp / out.name, project_files=[cfg])
        shutil.move(str(built), str(out))
    return out


__all__ = ['build_fmu', 'SLAVE_MODULE']
