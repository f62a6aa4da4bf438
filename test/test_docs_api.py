"""doc/reference/api.md, the Python API reference: every module of the package that exports
names (an ``__all__``) has its automodule there, and the page names no module that is gone."""

import ast
import re

from conftest import ROOT

PACKAGE = ROOT / 'servovalve_twin'
#: exporting modules the reference leaves out, and why
LEFT_OUT = {
    # the FMU's own runtime inside the .fmu (pythonfmu's slave class), not an API to call
    'servovalve_twin.fmu.slave',
}


def exporting_modules() -> set[str]:
    out = set()
    for path in PACKAGE.rglob('*.py'):
        tree = ast.parse(path.read_text(encoding='utf-8'))
        if any(isinstance(n, ast.Assign) and any(getattr(t, 'id', None) == '__all__'
                                                  for t in n.targets) for n in tree.body):
            parts = path.relative_to(ROOT).with_suffix('').parts
            out.add('.'.join(parts[:-1] if parts[-1] == '__init__' else parts))
    return out


def documented() -> set[str]:
    text = (ROOT / 'doc' / 'reference' / 'api.md').read_text(encoding='utf-8')
    return set(re.findall(r'^\.\. automodule:: (\S+)$', text, re.M))


def test_every_exporting_module_is_in_the_api_reference():
    missing = exporting_modules() - LEFT_OUT - documented()
    assert not missing, f'add to doc/reference/api.md: {sorted(missing)}'


def test_the_api_reference_names_only_modules_that_exist():
    for name in documented():
        rel = name.replace('.', '/')
        assert (ROOT / f'{rel}.py').is_file() or (ROOT / rel / '__init__.py').is_file(), name
