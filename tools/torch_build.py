"""Install the CPU build of the pinned torch into a virtual environment, wherever it runs.

    python tools/torch_build.py                      # what `make venv` runs (with the venv's python)
    TORCH_BUILD=cuda python tools/torch_build.py     # opt in to whatever pip resolves (CUDA on Linux)

The robots run torch on the CPU; on Linux x86_64 the public package index serves the CUDA
build (16 nvidia-* packages: a 5.2 GB venv, 707 MB of private memory per agent instead of
332 MB). So before the requirements are installed:

1. ask pip what ``torch==<pin of requirements.txt>`` resolves to from the configured sources
   (``pip install --dry-run --no-deps --report``): a CPU-only build (a ``+cpu`` version, or a
   wheel that requires no nvidia-* package, as on macOS or aarch64) is installed as it is;
2. otherwise ask PyTorch's CPU wheel index (``TORCH_CPU_INDEX``, default
   https://download.pytorch.org/whl/cpu) and install from there;
3. if neither has a CPU build, stop with exit status 2 and say how to get one, rather than
   silently pulling the CUDA build.

``TORCH_BUILD=cuda`` (or ``any``) skips all this: the requirements step then installs what pip
resolves (the CUDA build on Linux x86_64, for training on a GPU). Only the standard library is
used; pip is the venv's own (``python -m pip``).
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Callable, List, Optional

CPU_INDEX = 'https://download.pytorch.org/whl/cpu'
REPO = Path(__file__).resolve().parents[1]

#: (args) -> (returncode, report dict or None, stderr text); replaced in tests.
PipRunner = Callable[[List[str]], tuple]


def torch_pin(requirements: Path = REPO / 'requirements.txt') -> str:
    """The exact torch requirement of ``requirements.txt`` (``torch==X``)."""
    for line in requirements.read_text().splitlines():
        line = line.split('#', 1)[0].strip()
        if re.match(r'^torch\s*==', line):
            return line.replace(' ', '')
    raise SystemExit(f'tools/torch_build.py: no exact torch pin (torch==X) in {requirements}')


def is_cpu_build(item: dict) -> bool:
    """Whether a pip ``--report`` install item is a CPU-only torch build."""
    meta = item.get('metadata') or {}
    version = str(meta.get('version', ''))
    if '+cpu' in version:
        return True
    if re.search(r'\+(cu|rocm|xpu)', version):
        return False
    requires = meta.get('requires_dist') or []
    return not any(str(r).lower().startswith('nvidia-') for r in requires)


def _pip(args: List[str]) -> tuple:
    with tempfile.TemporaryDirectory() as tmp:
        report = Path(tmp) / 'report.json'
        proc = subprocess.run(
            [sys.executable, '-m', 'pip', *args, '--report', str(report)], capture_output=True, text=True
        )
        data = json.loads(report.read_text()) if report.is_file() else None
    return proc.returncode, data, proc.stderr


def resolve(pin: str, pip: PipRunner = _pip, index: Optional[str] = None) -> Optional[dict]:
    """The install item pip resolves ``pin`` to (from ``index`` only, when given), or None."""
    args = ['install', '--dry-run', '--quiet', '--no-deps', '--ignore-installed', pin]
    if index:
        args += ['--index-url', index]
    code, report, _ = pip(args)
    if code != 0 or not report or not report.get('install'):
        return None
    return report['install'][0]


def describe(item: dict) -> str:
    meta = item.get('metadata') or {}
    url = (item.get('download_info') or {}).get('url', '?')
    nvidia = [r for r in meta.get('requires_dist') or [] if str(r).lower().startswith('nvidia-')]
    extra = f', requires {len(nvidia)} nvidia-* packages' if nvidia else ''
    return f'torch {meta.get("version", "?")} from {url}{extra}'


def choose(pin: str, pip: PipRunner = _pip, cpu_index: str = CPU_INDEX) -> List[str]:
    """The pip install arguments that get a CPU build of ``pin``.

    Raises:
        SystemExit: (status 2) neither the configured sources nor ``cpu_index`` have one.
    """
    first = resolve(pin, pip)
    if first is not None and is_cpu_build(first):
        print(f'torch: {describe(first)} (a CPU build, from the configured sources)')
        return ['install', '--no-deps', pin]
    second = resolve(pin, pip, cpu_index)
    if second is not None and is_cpu_build(second):
        why = describe(first) if first is not None else 'nothing'
        print(f'torch: the configured sources give {why}; using {describe(second)}')
        return ['install', '--no-deps', pin, '--index-url', cpu_index]
    found = describe(first) if first is not None else f'no {pin} at all'
    print(
        f'tools/torch_build.py: error: no CPU build of {pin} is reachable: the configured package sources '
        f"give {found}, and PyTorch's CPU index {cpu_index} gave "
        f'{describe(second) if second is not None else "nothing (unreachable?)"}.\n'
        '  Either make the CPU index reachable (or set TORCH_CPU_INDEX to a mirror of it), or put the CPU '
        f'wheel into a folder and add it with PIP_FIND_LINKS, or accept the CUDA build '
        '(several GB; for training on a GPU) with TORCH_BUILD=cuda.',
        file=sys.stderr,
    )
    raise SystemExit(2)


def main(argv: Optional[List[str]] = None) -> int:
    build = os.environ.get('TORCH_BUILD', 'cpu').strip().lower()
    if build in ('cuda', 'any'):
        print(f'torch: TORCH_BUILD={build}: installing what pip resolves for the pin (no CPU check)')
        return 0
    if build != 'cpu':
        print(
            f'tools/torch_build.py: error: TORCH_BUILD={build!r}: use cpu (default) or cuda', file=sys.stderr
        )
        return 2
    pin = torch_pin()
    args = choose(pin, cpu_index=os.environ.get('TORCH_CPU_INDEX', CPU_INDEX))
    return subprocess.run([sys.executable, '-m', 'pip', *args]).returncode


if __name__ == '__main__':
    sys.exit(main())
