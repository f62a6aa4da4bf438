"""The twin's files: the ``config/`` directory (default parameters, built-in scenarios) and
reading scenarios by name or from YAML. The physics reads no files; it takes what this module
loads."""

from __future__ import annotations

import copy
import dataclasses
import functools
import sys
from pathlib import Path
from typing import Any, Mapping

from .errors import BagError, ScenarioError
from .physics.scenario import Scenario, scenario_from_dict


@functools.lru_cache(maxsize=None)
def config_dir() -> Path:
    """The ``config/`` directory: the source tree's (editable installs), else the one
    installed under ``share/servovalve_twin`` (pip's data_files or colcon). Looked up once
    per process (the failed ament import alone cost 0.1 ms per scenario load)."""
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


_BUILTIN_NAMES: dict[tuple[str, int], dict[str, Path]] = {}


def builtin_scenarios() -> dict[str, Path]:
    """Name -> file of the scenarios shipped in ``config/scenarios``: listed once per state of
    the folder (its modification time changes when a file is added, removed or renamed; the
    glob took 19 us of every ``simulate(model, 'paper')``)."""
    folder = config_dir() / 'scenarios'
    key = (str(folder), folder.stat().st_mtime_ns)
    if key not in _BUILTIN_NAMES:
        _BUILTIN_NAMES[key] = {p.stem: p for p in sorted(folder.glob('*.yaml'))}
    return dict(_BUILTIN_NAMES[key])


#: a scenario is a few kilobytes; anything this large is not one
MAX_YAML_BYTES = 1_000_000


def read_yaml(path: Path, what: str) -> Any:
    """A YAML file as data: UTF-8, at most :data:`MAX_YAML_BYTES`, and without anchors or
    aliases (a scenario needs none, and a 450-byte alias bomb expands to gigabytes)."""
    try:
        with open(path, 'rb') as fh:
            raw = fh.read(MAX_YAML_BYTES + 1)
    except OSError as exc:
        raise ScenarioError(f'cannot read {what} {str(path)!r}: {exc.strerror}') from None
    if len(raw) > MAX_YAML_BYTES:
        raise ScenarioError(f'{what} {str(path)!r} is larger than {MAX_YAML_BYTES} bytes')
    try:
        text = raw.decode('utf-8')
    except UnicodeDecodeError as exc:
        raise ScenarioError(f'{what} {str(path)!r} is not UTF-8 text (byte {exc.start})'
                            ) from None
    return load_yaml_text(text, f'{what} {str(path)!r}')


def load_yaml_text(text: str, what: str) -> Any:
    import yaml

    class _NoAliases(yaml.SafeLoader):
        def compose_node(self, parent, index):
            if self.check_event(yaml.AliasEvent):
                raise ScenarioError(f'{what} uses a YAML alias (*name); write the values out')
            event = self.peek_event()
            if getattr(event, 'anchor', None):
                raise ScenarioError(f'{what} uses a YAML anchor (&{event.anchor[:20]}); '
                                    'write the values out')
            return super().compose_node(parent, index)
    try:
        return yaml.load(text, Loader=_NoAliases)           # noqa: S506 -- a SafeLoader
    except yaml.YAMLError as exc:
        raise ScenarioError(f'{what} is not valid YAML: {str(exc).splitlines()[0][:200]}'
                            ) from None
    except RecursionError:                  # [[[... 100 000 deep was a traceback
        raise ScenarioError(f'{what} is nested too deeply') from None
    except ValueError as exc:               # an integer of more than 4300 digits
        raise ScenarioError(f'{what} holds a value that cannot be read: {str(exc)[:80]}'
                            ) from None


_BUILTIN: dict[tuple[str, int, int, str], Scenario] = {}


def _builtin_scenario(path: Path, name: str) -> Scenario:
    """A built-in scenario, read and validated once per process and content: PyYAML took 2 ms
    of a 2.6 ms ``simulate('C2', 'paper')``, the validation 52 us of a 2.0 ms one. A changed
    file (size or mtime) is read again. The caller gets its own copies of the mutable parts
    (params, windows, faults), so its changes stay its own; the profiles and sensors are
    frozen and shared."""
    st = path.stat()
    key = (str(path), st.st_mtime_ns, st.st_size, name)
    if key not in _BUILTIN:
        _BUILTIN[key] = scenario_from_dict(read_yaml(path, 'scenario'), name=name)
    scn = _BUILTIN[key]
    return dataclasses.replace(scn, params=dict(scn.params), windows=dict(scn.windows),
                               faults=copy.deepcopy(scn.faults))


def load_scenario(spec: str | Path | Mapping[str, Any] | Scenario) -> Scenario:
    """A scenario by built-in name (``paper``), YAML file path, mapping, or as is."""
    if isinstance(spec, Scenario):
        return spec
    if isinstance(spec, Mapping):
        return scenario_from_dict(spec)
    text = str(spec)
    builtins = builtin_scenarios()
    if text in builtins:
        return _builtin_scenario(builtins[text], text)
    path = Path(text)
    if path.suffix in ('.yaml', '.yml') or path.exists():
        return scenario_from_dict(read_yaml(path, 'scenario file'), name=path.stem)
    raise ScenarioError(f'unknown scenario {text!r}: not a built-in name {sorted(builtins)} '
                        'and not a YAML file')


def reference_dir() -> Path:
    """The packaged reference bags (``servovalve_twin/data``), read-only to every command."""
    return Path(__file__).resolve().parent / 'data'


def reference_bags() -> dict[str, Path]:
    return {p.name: p for p in sorted(reference_dir().iterdir()) if p.is_dir()}


def resolve_bag(spec: str | Path) -> Path:
    """A bag path; ``@NAME`` names a packaged reference bag (``@paper_HD``)."""
    text = str(spec)
    if text.startswith('@'):
        refs = reference_bags()
        if text[1:] not in refs:
            raise BagError(f'unknown reference bag {text!r}; the package holds '
                                f'{["@" + n for n in refs]}')
        return refs[text[1:]]
    return Path(text)


def safe_name(name: str) -> str:
    """A scenario or model name as a single, harmless path component (``../../x`` -> ``x``)."""
    import re
    cleaned = re.sub(r'[^A-Za-z0-9_.-]+', '_', str(name)).strip('._') or 'run'
    return cleaned[:80]


def default_bag_dir(scenario_name: str, valve_model: str, root: str | Path = 'bags') -> Path:
    """``bags/<scenario>_<model>_<UTC time>`` (rosbag2's convention: a timestamped directory),
    never an existing one: the contents are reproducible, the name never collides."""
    import datetime
    stamp = datetime.datetime.now(datetime.timezone.utc).strftime('%Y-%m-%d-%H-%M-%S')
    base = Path(root) / f'{safe_name(scenario_name)}_{safe_name(valve_model)}_{stamp}'
    path, n = base, 1
    while path.exists():
        n += 1
        path = base.with_name(f'{base.name}_{n}')
    return path
