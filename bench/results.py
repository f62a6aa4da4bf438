"""Results pages as outputs: a bench writes its tables into a page of ``doc/results/`` itself,
between two markers, from the JSON it leaves beside the page (``doc/results/data/``), so a
figure in the docs is never re-typed by hand; ``test/test_results_pages.py`` renders each
committed JSON again and checks that the page holds exactly that.

    <!-- results: NAME, written by COMMAND: do not edit -->
    ...the bench's tables...
    <!-- end of results: NAME -->

A bench opts in with ``--doc``: it writes ``doc/results/data/NAME.json`` and the section NAME
of its page (which must already hold the two markers: a page's prose around them is the
author's, the section the bench's).
"""

from __future__ import annotations

import json
import os
import re
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / 'doc' / 'results' / 'data'


def _markers(name: str) -> re.Pattern:
    return re.compile(r'(<!-- results: ' + re.escape(name) + r', written by [^\n]*-->\n)'
                      r'(.*?)'
                      r'(<!-- end of results: ' + re.escape(name) + r' -->)', re.S)


def section(page: Path, name: str) -> str:
    """The text between the markers of ``name`` in ``page``."""
    m = _markers(name).search(page.read_text(encoding='utf-8'))
    if m is None:
        raise SystemExit(f'{page}: no section {name!r} (markers "<!-- results: {name}, written '
                         f'by ... -->" and "<!-- end of results: {name} -->")')
    return m.group(2)


def _replace(path: Path, text: str) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f'.{path.name}.')
    with os.fdopen(fd, 'w', encoding='utf-8') as fh:
        fh.write(text)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)            # a file's usual mode, not mkstemp's 0600
    os.replace(tmp, path)


def command_line(argv: list[str] | None = None) -> str:
    """The command that is running, as the README prints commands."""
    argv = sys.argv if argv is None else argv
    script = os.path.relpath(os.path.abspath(argv[0]), ROOT)
    return ' '.join(['.venv/bin/python', script, *argv[1:]])


def write(page: Path, name: str, data: dict, markdown: str, command: str | None = None
          ) -> None:
    """``data`` to ``doc/results/data/NAME.json`` and ``markdown`` into ``page``'s section,
    its opening marker naming ``command`` (default: the one running)."""
    section(page, name)                                 # refuses a page without the markers
    DATA.mkdir(parents=True, exist_ok=True)
    _replace(DATA / f'{name}.json', json.dumps(data, indent=1, default=float) + '\n')
    text = page.read_text(encoding='utf-8')
    opening = (f'<!-- results: {name}, written by {command or command_line()}: do not '
               'edit -->\n')
    body = markdown.rstrip('\n') + '\n'
    _replace(page, _markers(name).sub(lambda m: opening + body + m.group(3), text, count=1))


def load(name: str) -> dict:
    return json.loads((DATA / f'{name}.json').read_text(encoding='utf-8'))
