"""Shared pytest setup for knode_swarm_ros.

Sections: environment for ROS processes started by tests, then fixtures. Add new
fixtures in their own section below; keep this module free of heavy imports (torch,
rclpy) so that collection stays fast and tests that need neither never load them.
"""

import os
import sys

import pytest

# --- Environment -----------------------------------------------------------------
# Set at import time, before any test module runs, so child processes inherit it.
# ROS traffic never leaves this machine.
os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')

# The virtual environment is an ament prefix: the ros-jazzy-* wheels and this package
# (`make` copies package.xml, the index marker and config/ there) register under
# <sys.prefix>/share, so ament_index_python finds them once the prefix is listed.
_ament = [p for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
if sys.prefix not in _ament:
    os.environ['AMENT_PREFIX_PATH'] = os.pathsep.join([sys.prefix] + _ament)

# Note for tests that start processes: the ros-jazzy-* wheels re-exec Python with
# LD_LIBRARY_PATH set and _ROS_WHEELS_BOOTSTRAP_COMPLETE=1. A child must inherit both
# or neither; start children with a copy of os.environ and edit other keys only.


# --- ROS domains ------------------------------------------------------------------
# ROS_DOMAIN_ID 0 is everyone's default: never used here. 1..101 are valid on Linux
# with the default port mapping. Every domain a test uses is claimed with an exclusive lock
# file (knode_swarm_ros.nodes.swarm.domains), so two copies of the suite running at once (or a
# swarm started by hand) never share one; the claim ends with the test.
_DOMAIN_MIN, _DOMAIN_MAX = 1, 101


def claim_ros_domain():
    """A :class:`DomainClaim` on a free domain id in 1..101 (``.domain_id``; ``.release()``)."""
    from knode_swarm_ros.nodes.swarm.domains import claim_domain

    return claim_domain(range(_DOMAIN_MIN, _DOMAIN_MAX + 1))


@pytest.fixture
def ros_domain_id(monkeypatch):
    """A ROS_DOMAIN_ID of this test's own (int), claimed for the test's duration, also set in
    os.environ for the test (and so for the processes it starts); the previous value returns
    afterwards."""
    claim = claim_ros_domain()
    monkeypatch.setenv('ROS_DOMAIN_ID', str(claim.domain_id))
    yield claim.domain_id
    claim.release()


# --- Markers (added with the ROS nodes; owner: knode_swarm_ros/nodes) ------------------
# `ros`: tests that start ROS 2 nodes, in this process on an isolated domain or as
# separate processes (tests/test_ros_*.py). Deselect them with `pytest -m "not ros"`.
def pytest_configure(config):
    config.addinivalue_line(
        'markers',
        'ros: starts ROS 2 nodes (in-process rclpy or multi-process swarms); deselect with -m "not ros"',
    )
    # TorchScript is deprecated upstream (torch 2.10+) but stays this project's policy format
    # (docs/testing.md, "Warnings"); the library silences it where it scripts, tests that script
    # their own modules would repeat it on every run.
    for api in TORCHSCRIPT_DEPRECATED:
        config.addinivalue_line('filterwarnings', f'ignore:`{api}` is deprecated:DeprecationWarning')


#: The torch.jit calls whose upstream deprecation notice the suite does not repeat.
TORCHSCRIPT_DEPRECATED = (
    'torch.jit.script',
    'torch.jit.script_method',
    'torch.jit.trace',
    'torch.jit.interface',
    'torch.jit.load',
    'torch.jit.save',
)


# --- policy files ------------------------------------------------------------------------


@pytest.fixture(scope='session')
def untrained_policies(tmp_path_factory):
    """Seeded, untrained policy files of both scenarios, ``{scenario: path}``: node and
    swarm tests must not depend on the shipped, trained ones."""
    import torch

    from knode_swarm_ros.core import DEFAULTS, KNODEPolicy, PolicyConfig, export_policy

    out = {}
    for scenario in ('flock2d', 'boids3d'):
        torch.manual_seed(3)
        policy = KNODEPolicy(PolicyConfig(scenario, **DEFAULTS[scenario]))
        path = tmp_path_factory.mktemp('policies') / f'{scenario}.pt'
        export_policy(policy, path, policy.metadata())
        out[scenario] = path
    return out


# --- No silent skips -----------------------------------------------------------
# A skipped test is not a pass. With CI=true (or KNODE_NO_SKIPS=1) any skip fails the run
# unless its test id starts with an entry of SKIP_ALLOW_LIST (each with the reason it may
# skip there); every skip is listed at the end either way. Keep the list short.
# Empty on purpose: `make test` installs everything the suite needs (colcon included), so
# nothing has a reason to skip there. Entry format: 'tests/test_x.py::test_y': 'why'.
SKIP_ALLOW_LIST = {}
_skips = []


def _strict_skips() -> bool:
    return any(os.environ.get(k, '').lower() in ('1', 'true', 'yes') for k in ('CI', 'KNODE_NO_SKIPS'))


def _allowed(nodeid: str):
    return next((why for prefix, why in SKIP_ALLOW_LIST.items() if nodeid.startswith(prefix)), None)


def _note_skip(report):
    if report.skipped and not hasattr(report, 'wasxfail'):
        reason = report.longrepr[2] if isinstance(report.longrepr, tuple) else str(report.longrepr)
        _skips.append((report.nodeid, reason))


def pytest_runtest_logreport(report):
    _note_skip(report)


def pytest_collectreport(report):
    _note_skip(report)  # a whole module skipped at import time


def pytest_sessionfinish(session, exitstatus):
    if (
        _strict_skips()
        and any(_allowed(nodeid) is None for nodeid, _ in _skips)
        and session.exitstatus == pytest.ExitCode.OK
    ):
        session.exitstatus = pytest.ExitCode.TESTS_FAILED


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    strict = _strict_skips()
    if strict:
        allowed = '; '.join(f'{k} ({v})' for k, v in SKIP_ALLOW_LIST.items()) or 'empty'
        terminalreporter.write_line(f'no-skip rule on (CI): {len(_skips)} skipped; allow-list: {allowed}')
    if not _skips:
        return
    terminalreporter.section('skipped tests (a skip is not a pass)')
    for nodeid, reason in _skips:
        why = _allowed(nodeid)
        verdict = (
            f'allowed: {why}'
            if why
            else ('NOT ALLOWED in CI: fails the run' if strict else 'not allowed in CI')
        )
        terminalreporter.write_line(f'{nodeid}: {reason} [{verdict}]')


# --- hypothesis profiles (tests/test_fuzz.py; docs/testing.md, "Fuzzing") ---------------------------
# `suite` (the default): a fixed seed, so a failure in CI reproduces; each test sets its own small
# budget. `fuzz` (HYPOTHESIS_PROFILE=fuzz, `make fuzz`): the same seed-free search, 10,000
# examples per reader (tests/test_fuzz.py reads the profile's name). No example database: a
# failure is kept as an @example in the test instead.
try:
    from hypothesis import settings as _hypothesis_settings
except ImportError:  # hypothesis is a dev dependency; without it test_fuzz.py fails to import
    pass
else:
    _hypothesis_settings.register_profile(
        'suite', derandomize=True, deadline=None, database=None, print_blob=True
    )
    _hypothesis_settings.register_profile(
        'fuzz', derandomize=False, deadline=None, database=None, print_blob=True
    )
    _hypothesis_settings.load_profile(os.environ.get('HYPOTHESIS_PROFILE', 'suite'))
