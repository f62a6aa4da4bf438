"""bench/results.py and the results pages it writes: every section a bench wrote into
doc/results/ holds exactly what that bench renders from the JSON it left beside the page (a
figure typed over by hand, or a JSON committed without its page, fails)."""

import importlib
import json
import re
import sys

import pytest

from conftest import ROOT

sys.path.insert(0, str(ROOT / 'bench'))
import results  # noqa: E402

OPENING = re.compile(r'<!-- results: ([\w.-]+), written by \S+ (bench/\w+\.py)[^\n]*-->')


def sections():
    for page in sorted((ROOT / 'doc' / 'results').glob('*.md')):
        for name, script in OPENING.findall(page.read_text(encoding='utf-8')):
            yield pytest.param(page, name, script, id=name)


def test_some_page_is_written_by_a_bench():
    assert list(sections())


@pytest.mark.parametrize('page,name,script', list(sections()))
def test_a_results_section_is_what_its_bench_renders_from_its_json(page, name, script):
    bench = importlib.import_module(script.removeprefix('bench/').removesuffix('.py'))
    assert results.section(page, name) == bench.render(results.load(name))


def test_every_json_has_its_section():
    named = {p.values[1] for p in sections()}
    assert {p.stem for p in results.DATA.glob('*.json')} <= named


def test_write_replaces_its_section_only(tmp_path, monkeypatch):
    monkeypatch.setattr(results, 'DATA', tmp_path / 'data')
    page = tmp_path / 'page.md'
    page.write_text('# Title\n\nprose before\n\n<!-- results: x, written by old: do not edit -->\n'
                    'stale | table\n<!-- end of results: x -->\n\nprose after\n')
    results.write(page, 'x', {'a': 1}, '| new | table |\n', command='.venv/bin/python b.py')
    assert page.read_text() == (
        '# Title\n\nprose before\n\n<!-- results: x, written by .venv/bin/python b.py: do not '
        'edit -->\n| new | table |\n<!-- end of results: x -->\n\nprose after\n')
    assert json.loads((tmp_path / 'data' / 'x.json').read_text()) == {'a': 1}
    assert results.section(page, 'x') == '| new | table |\n'
    with pytest.raises(SystemExit, match="no section 'y'"):
        results.write(page, 'y', {}, '')
    assert not (tmp_path / 'data' / 'y.json').exists()
