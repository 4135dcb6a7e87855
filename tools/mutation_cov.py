"""pytest plugin of tools/mutation.py: which test runs which line.

    python -m pytest -p tools.mutation_cov ...   (env MUTATION_COV_OUT=<file.json>)

Starts coverage before the test modules are collected and switches its context to the
test id around each test (setup, call and teardown), so every line of ``knode_swarm_ros``
is mapped to the tests that execute it in this process. Lines run at import time keep the
empty context. Writes ``{"lines": {file: {line: [test ids]}}, "durations": {test id: s}}``.
Code run in child processes or only inside TorchScript is not seen: the mutation runner
falls back to every test of the module for such lines.
"""

import json
import os
from pathlib import Path

import coverage
import pytest

_SRC = Path(os.getcwd()) / 'knode_swarm_ros'
_COV = coverage.Coverage(data_file=None, source=[str(_SRC)], branch=False)
_COV.start()
_DURATIONS = {}


@pytest.hookimpl(hookwrapper=True, tryfirst=True)
def pytest_runtest_protocol(item, nextitem):
    _COV.switch_context(item.nodeid)
    yield
    _COV.switch_context('')


def pytest_runtest_logreport(report):
    _DURATIONS[report.nodeid] = _DURATIONS.get(report.nodeid, 0.0) + report.duration


def pytest_sessionfinish(session, exitstatus):
    _COV.stop()
    data = _COV.get_data()
    lines = {}
    for name in data.measured_files():
        rel = os.path.relpath(name, os.getcwd())
        by_line = data.contexts_by_lineno(name)
        lines[rel] = {str(k): sorted(v) for k, v in by_line.items()}
    Path(os.environ['MUTATION_COV_OUT']).write_text(json.dumps({'lines': lines, 'durations': _DURATIONS}))
