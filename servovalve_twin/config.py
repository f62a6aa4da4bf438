"""The twin's files: the ``config/`` directory (default parameters, built-in scenarios) and
reading scenarios by name or from YAML. The physics reads no files; it takes what this module
loads."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any, Mapping

from .errors import ScenarioError
from .physics.scenario import Scenario, scenario_from_dict


def config_dir() -> Path:
    """The ``config/`` directory: the source tree's (editable installs), else the one
    installed under ``share/servovalve_twin`` (pip's data_files or colcon)."""
    candidates = [Path(__file__).resolve().parents[1] / 'config',
                  Path(sys.prefix) / 'share' / 'servovalve_twin' / 'config']
    try:
        from ament_index_python.packages import get_package_share_directory
        candidates.append(Path(get_package_share_directory('servovalve_twin')) / 'config')
    except Exception:  # noqa: BLE001 -- ament index absent or package not registered there
        pass
    for path in candidates:
        if (path / 'eha.yaml').is_file():
            return path
    raise ScenarioError('cannot find the config/ directory (eha.yaml) of servovalve_twin; '
                        f'looked in {[str(p) for p in candidates]}')


def builtin_scenarios() -> dict[str, Path]:
    """Name -> file of the scenarios shipped in ``config/scenarios``."""
    return {p.stem: p for p in sorted((config_dir() / 'scenarios').glob('*.yaml'))}


def read_yaml(path: Path, what: str) -> Any:
    import yaml
    try:
        with open(path, encoding='utf-8') as fh:
            return yaml.safe_load(fh)
    except OSError as exc:
        raise ScenarioError(f'cannot read {what} {str(path)!r}: {exc.strerror}') from None
    except yaml.YAMLError as exc:
        raise ScenarioError(f'{what} {str(path)!r} is not valid YAML: '
                            f'{str(exc).splitlines()[0]}') from None


def load_scenario(spec: str | Path | Mapping[str, Any] | Scenario) -> Scenario:
    """A scenario by built-in name (``paper``), YAML file path, mapping, or as is."""
    if isinstance(spec, Scenario):
        return spec
    if isinstance(spec, Mapping):
        return scenario_from_dict(spec)
    text = str(spec)
    builtins = builtin_scenarios()
    if text in builtins:
        return scenario_from_dict(read_yaml(builtins[text], 'scenario'), name=text)
    path = Path(text)
    if path.suffix in ('.yaml', '.yml') or path.exists():
        return scenario_from_dict(read_yaml(path, 'scenario file'), name=path.stem)
    raise ScenarioError(f'unknown scenario {text!r}: not a built-in name {sorted(builtins)} '
                        'and not a YAML file')
