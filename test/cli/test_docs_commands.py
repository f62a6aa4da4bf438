"""The command lines the README and the docs print (servovalve_twin.cli as a reader meets it):
every ``servovalve-twin`` line of their command blocks parses as printed (a renamed option or
command fails here, naming the page and line), and the README's tour runs as printed, in
order, in a scratch directory."""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from servovalve_twin.cli import build_parser
from conftest import ROOT

PAGES = [ROOT / 'README.md', *sorted((ROOT / 'doc').glob('*/*.md'))]


def command_lines(page: Path) -> list[tuple[int, str]]:
    """(line number, command) of each ``servovalve-twin`` line of the page's indented command
    blocks (continuation lines joined, a trailing comment dropped) and of its code spans."""
    out = []
    lines = page.read_text(encoding='utf-8').splitlines()
    i = 0
    while i < len(lines):
        text = lines[i].strip()
        start = i
        while text.endswith('\\') and i + 1 < len(lines):
            i += 1
            text = text[:-1] + ' ' + lines[i].strip()
        i += 1
        indented = lines[start].startswith('    ')
        if indented and text.startswith('servovalve-twin '):
            out.append((start + 1, re.sub(r'\s+#.*$', '', text).rstrip(' &')))
        elif not indented:
            # and the commands prose quotes: `servovalve-twin ...` in code spans
            # (a command's name alone, or COMMAND, is a mention, not a command line)
            out += [(start + 1, m) for m in re.findall(r'`(servovalve-twin [^`]+)`', text)
                    if len(m.split()) > 2 and not m.split()[1].isupper()]
    return out


def _template(cmd: str) -> bool:
    """A synopsis rather than a command: optional parts in brackets, alternatives, '...'."""
    return any(s in cmd for s in ('[', ' | ', '...'))


CASES = [pytest.param(cmd, id=f'{page.relative_to(ROOT)}:{n}')
         for page in PAGES for n, cmd in command_lines(page) if not _template(cmd)]


def test_the_pages_print_commands():
    assert len(CASES) >= 20, [c.id for c in CASES]


@pytest.mark.parametrize('cmd', CASES)
def test_every_printed_command_parses(cmd):
    """Placeholders (BAG, SCENARIO) stand where the user's names go: the parser takes them as
    the strings they are; a renamed option or command is an argparse error (exit 2)."""
    import contextlib
    import io
    argv = shlex.split(cmd)[1:]
    err = io.StringIO()
    try:
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
            build_parser().parse_args(argv)
    except SystemExit as exc:
        if exc.code:                            # 0: a --help printed
            pytest.fail(f'{cmd!r} does not parse: {err.getvalue().strip().splitlines()[-1]}')


#: the README's tour, in its order: each line as printed (placeholders and a ROS machine's
#: ros2 lines aside), each must exit 0
TOUR = [cmd for n, cmd in command_lines(ROOT / 'README.md')
        if (ROOT / 'README.md').read_text().splitlines()[n - 1].startswith('    ')
        and not _template(cmd) and not re.search(r'\b[A-Z][A-Z0-9_]{2,}\b', cmd)
        and ' report' not in cmd]


@pytest.mark.ros
@pytest.mark.slow
def test_the_readme_tour_runs_as_printed(tmp_path):
    """simulate, compare, run (bags/hd), diagnose of that bag, the limits of the paper
    flight, the built-in test: as printed, from a scratch directory that holds the
    repository's config/ and doc/ (paths the README names)."""
    for d in ('config', 'doc'):
        os.symlink(ROOT / d, tmp_path / d)
    assert len(TOUR) >= 6, TOUR
    for cmd in TOUR:
        r = subprocess.run([sys.executable, '-m', 'servovalve_twin.cli', *shlex.split(cmd)[1:]],
                           cwd=tmp_path, capture_output=True, text=True, timeout=900)
        assert r.returncode == 0, (cmd, r.stdout[-1500:], r.stderr[-1500:])
