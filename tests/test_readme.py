"""README.md's command blocks, run as written in a fresh copy of the repository.

Every ```bash block of the README carries a marker comment on the line before it:
``<!-- readme-test: run -->`` (this module runs it) or ``<!-- readme-test: not run: WHY -->``.
The runnable blocks run in order, in one temporary copy of the tracked files (with this
checkout's ``.venv``), each with ``bash -e``; a block passes when it exits 0 and prints no
traceback and no warning. Full-size blocks are not run: the README offers a quick block of the
same commands beside each.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BLOCK = re.compile(r'(?:<!-- readme-test: (run|not run: [^>]+?) -->\n)?```bash\n(.*?)```', re.S)


def readme_blocks():
    """``[(line, marker or None, text)]`` of every bash block of README.md."""
    text = (ROOT / 'README.md').read_text()
    return [(text[: m.start()].count('\n') + 1, m.group(1), m.group(2)) for m in BLOCK.finditer(text)]


RUN = [(line, text) for line, marker, text in readme_blocks() if marker == 'run']


def test_every_readme_block_says_whether_it_runs():
    unmarked = [line for line, marker, _ in readme_blocks() if marker is None]
    assert not unmarked, f'README.md bash blocks without a readme-test marker at lines {unmarked}'
    assert len(RUN) >= 3


def test_the_readme_says_to_activate_the_venv_before_its_first_command():
    text = (ROOT / 'README.md').read_text()
    first = text.index('python -m training.')
    assert 'source .venv/bin/activate' in text[:first]


@pytest.fixture(scope='module')
def clone(tmp_path_factory):
    """A copy of the repository's tracked and unignored files, as a fresh clone has them."""
    dest = tmp_path_factory.mktemp('readme') / 'repo'
    files = subprocess.run(
        ['git', 'ls-files', '-co', '--exclude-standard', '-z'], cwd=ROOT, capture_output=True, check=True
    ).stdout.split(b'\0')
    for name in filter(None, (f.decode() for f in files)):
        src = ROOT / name
        if name == '.venv' or not src.is_file():
            continue
        (dest / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(src, dest / name)
    (dest / '.venv').symlink_to((ROOT / '.venv').resolve())
    return dest


@pytest.mark.parametrize(
    'line, text',
    [pytest.param(*b, id=f'line{b[0]}', marks=[pytest.mark.ros] * ('swarm ' in b[1])) for b in RUN],
)
def test_readme_block_runs_as_written(clone, line, text):
    env = dict(os.environ, PYTHONPATH=str(clone))  # the copy's code, not an installed one
    env['PATH'] = os.pathsep.join([str(clone / '.venv' / 'bin'), env.get('PATH', '')])
    env.pop('ROS_DOMAIN_ID', None)
    res = subprocess.run(
        ['bash', '-e', '-o', 'pipefail', '-c', text],
        cwd=clone,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    out = res.stdout + res.stderr
    assert res.returncode == 0, f'README.md line {line}: exit {res.returncode}\n{out[-4000:]}'
    assert 'Traceback' not in out, out[-4000:]
    warnings = [ln for ln in out.splitlines() if re.search(r'\bwarn(ing)?\b', ln, re.I)]
    assert not warnings, f'README.md line {line} printed warnings: {warnings[:5]}'
