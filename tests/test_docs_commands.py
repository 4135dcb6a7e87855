"""Every ``python -m training.X`` that README.md and docs/ name is a command with a working ``--help``.

Names are collected from the Markdown and the config comments; the helps run in one subprocess
(one torch import) through ``runpy``, as ``python -m`` runs them.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
COMMAND = re.compile(
    r'python3? -m (training(?:\.[a-z0-9_]+)+)(?![.\w<])'
)  # not a pattern: training.studies.<name>


def documented_commands():
    files = [
        ROOT / 'README.md',
        *sorted((ROOT / 'docs').glob('*.md')),
        *sorted((ROOT / 'config').glob('*.yaml')),
    ]
    files += [ROOT / 'knode_swarm_ros' / 'policies' / 'README.md']
    found = {}
    for path in files:
        for name in COMMAND.findall(path.read_text()):
            found.setdefault(name, path.relative_to(ROOT).as_posix())
    return found


PROBE = r"""
import contextlib, io, json, runpy, sys
out = {}
for name in json.loads(sys.argv[1]):
    buf = io.StringIO()
    sys.argv = [name, '--help']
    code = 'returned'
    try:
        with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(io.StringIO()):
            runpy.run_module(name, run_name='__main__', alter_sys=True)
    except SystemExit as exc:
        code = exc.code
    except BaseException as exc:  # an import error or a crash: reported by name
        code = f'{type(exc).__name__}: {exc}'
    out[name] = [code, buf.getvalue()]
print(json.dumps(out))
"""


def test_every_documented_training_command_has_a_working_help():
    found = documented_commands()
    assert {'training.generate', 'training.train', 'training.evaluate', 'training.import_bag'} <= set(found)
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    res = subprocess.run(
        [sys.executable, '-c', PROBE, json.dumps(sorted(found))],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env=env,
        timeout=600,
    )
    assert res.returncode == 0, res.stderr[-3000:]
    results = json.loads(res.stdout.strip().splitlines()[-1])
    bad = {
        name: f'{found[name]}: exit {code!r}, help {text[:80]!r}'
        for name, (code, text) in results.items()
        if code not in (0, None) or 'usage:' not in text or '--help' not in text
    }
    assert not bad, bad
