"""The package installs the way ROS 2 expects.

1. colcon builds it in a temporary workspace (the repository stays untouched), and the
   executables resolve the way `ros2 run knode_swarm_ros <exe>` resolves them: the
   package prefix from the ament index, then `<prefix>/lib/knode_swarm_ros/<exe>`. The
   agent is then started as `ros2 run` would start it, in the environment that
   `source install/setup.bash` gives.
2. The virtual environment that `make` builds is an ament prefix too, so
   `get_package_share_directory('knode_swarm_ros')` works there without colcon.

Until the ROS nodes land, an executable may be the placeholder that exits with status 2
and "node not available yet"; set ACCEPT_PLACEHOLDER_NODES = False once they have.
"""

import importlib.metadata
import importlib.util
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

PACKAGE = 'knode_swarm_ros'
EXECUTABLES = ('agent', 'agents', 'simulator', 'recorder', 'swarm', 'monitor')
REPO = Path(__file__).resolve().parents[1]

# Tighten here once knode_swarm_ros/nodes/agent/node.py is the real node.
ACCEPT_PLACEHOLDER_NODES = False
PLACEHOLDER_EXIT_CODE = 2
PLACEHOLDER_MESSAGE = 'node not available yet'
AGENT_ARGS = ('--ros-args', '-p', 'id:=3')
UP_LINE = 'publishing /robot_3/cmd_'  # the agent's start-up log line: the node is up
UP_TIMEOUT_S = 180.0
SHUTDOWN_TIMEOUT_S = 30.0  # generous: the suite runs on loaded machines (bench/ measures the 2 s)
COLCON_TIMEOUT_S = 240

# Never copied into the temporary workspace when git cannot list the files.
_IGNORED_ANYWHERE = {'.git', '__pycache__', '.pytest_cache', '.mypy_cache', '.ruff_cache'}
_IGNORED_AT_TOP = {'build', 'install', 'log', 'runs', 'data', 'out'}

needs_colcon = pytest.mark.skipif(
    importlib.util.find_spec('colcon_core') is None or importlib.util.find_spec('colcon_ros') is None,
    reason='colcon (colcon-common-extensions) is not installed in this interpreter: '
    'the ros2-run layout check needs it (pip install -r requirements-dev.txt, '
    'or `make test`, which does)',
)


def _source_files(repo):
    """Relative paths of the files a checkout has: tracked and untracked, not ignored."""
    try:
        out = subprocess.run(
            ['git', '-C', str(repo), 'ls-files', '-z', '--cached', '--others', '--exclude-standard'],
            check=True,
            capture_output=True,
            timeout=30,
        ).stdout
        files = [Path(p) for p in out.decode().split('\0') if p]
        return [p for p in files if (repo / p).is_file()]
    except (OSError, subprocess.SubprocessError):
        pass
    files = []
    for dirpath, dirnames, filenames in os.walk(repo):
        here = Path(dirpath)
        top = here == repo
        dirnames[:] = [
            d
            for d in dirnames
            if d not in _IGNORED_ANYWHERE
            and not d.endswith('.egg-info')
            and not (top and (d in _IGNORED_AT_TOP or d.startswith('.venv')))
            and not (here / d / 'pyvenv.cfg').exists()
        ]
        files += [(here / f).relative_to(repo) for f in filenames if not f.endswith(('.pyc', '.pyo'))]
    return files


def _copy_sources(repo, dest):
    for rel in _source_files(repo):
        target = dest / rel
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(repo / rel, target)


def _repo_artifacts(repo):
    """Build outputs that a colcon or setuptools run could leave in the repository."""
    found = {p.name for p in repo.glob('*.egg-info')}
    found |= {name for name in ('build', 'install', 'log') if (repo / name).exists()}
    return found


def _sourced_environment(setup_bash, base_env):
    """os.environ after `source setup_bash` in bash, as a user's shell would have it."""
    out = subprocess.run(
        ['bash', '-c', 'source "$1" >/dev/null && env -0', 'bash', str(setup_bash)],
        env=base_env,
        check=True,
        capture_output=True,
        timeout=60,
    ).stdout
    env = {}
    for item in out.decode().split('\0'):
        if '=' in item:
            key, value = item.split('=', 1)
            env[key] = value
    return env


def _executable_path(prefix, name):
    """What `ros2 run` finds: an executable file <prefix>/lib/<package>/<name>."""
    path = Path(prefix) / 'lib' / PACKAGE / name
    assert path.is_file(), (
        f'{path} is missing; lib/{PACKAGE} holds {sorted(p.name for p in path.parent.glob("*"))}'
    )
    assert os.access(path, os.X_OK), f'{path} is not executable'
    return path


@pytest.fixture(scope='module')
def colcon_workspace(tmp_path_factory):
    """Build the package with colcon in a fresh workspace; return its paths."""
    ws = tmp_path_factory.mktemp('colcon_ws')
    src = ws / 'src' / PACKAGE
    _copy_sources(REPO, src)
    before = _repo_artifacts(REPO)
    cmd = [
        sys.executable,
        '-m',
        'colcon',
        '--log-base',
        str(ws / 'log'),
        'build',
        '--base-paths',
        str(ws / 'src'),
        '--build-base',
        str(ws / 'build'),
        '--install-base',
        str(ws / 'install'),
        '--event-handlers',
        'console_cohesion+',
        'console_direct-',
    ]
    env = dict(os.environ)
    env.pop('COLCON_PREFIX_PATH', None)
    proc = subprocess.run(cmd, cwd=ws, env=env, capture_output=True, text=True, timeout=COLCON_TIMEOUT_S)
    assert proc.returncode == 0, f'colcon build failed ({proc.returncode}):\n{proc.stdout}\n{proc.stderr}'
    assert _repo_artifacts(REPO) == before, 'the colcon build wrote into the repository'
    leftovers = sorted(p.name for p in src.glob('*.egg-info'))
    leftovers += [d for d in ('build', 'install', 'log') if (src / d).exists()]
    assert not leftovers, f'the colcon build wrote into the source tree: {leftovers}'
    return {
        'ws': ws,
        'src': src,
        'install': ws / 'install',
        'sourced_env': _sourced_environment(ws / 'install' / 'setup.bash', env),
    }


@needs_colcon
def test_colcon_install_has_ros2_run_layout(colcon_workspace, monkeypatch):
    from ament_index_python.packages import get_package_prefix, get_package_share_directory

    install, src = colcon_workspace['install'], colcon_workspace['src']
    env = colcon_workspace['sourced_env']
    ament = env.get('AMENT_PREFIX_PATH', '')
    assert str(install / PACKAGE) in ament.split(os.pathsep), (
        f'setup.bash did not put the package on AMENT_PREFIX_PATH: {ament!r}'
    )

    monkeypatch.setenv('AMENT_PREFIX_PATH', ament)
    prefix = Path(get_package_prefix(PACKAGE))
    assert prefix == install / PACKAGE
    share = Path(get_package_share_directory(PACKAGE))
    assert (share / 'package.xml').is_file()
    assert (share / 'package.xml').read_bytes() == (src / 'package.xml').read_bytes()
    for config in sorted((src / 'config').rglob('*')):
        if config.is_file():
            rel = config.relative_to(src)
            assert (share / rel).is_file(), f'{rel} is not installed under {share}'

    for name in EXECUTABLES:
        exe = _executable_path(prefix, name)
        shebang = exe.read_text().splitlines()[0]
        assert shebang.startswith('#!'), f'{exe} has no interpreter line'
        interpreter = shebang[2:].strip().split()[0]
        assert os.access(interpreter, os.X_OK), f'{exe}: interpreter {interpreter} missing'

    # Every module of the package is installed (a folder without __init__.py would
    # silently be left out by find_packages), and so are the shipped policies.
    site = [
        Path(p)
        for p in env.get('PYTHONPATH', '').split(os.pathsep)
        if p and Path(p).is_relative_to(install / PACKAGE)
    ]
    assert len(site) == 1, f'expected one site-packages of the install on PYTHONPATH: {site}'
    for source in sorted((src / PACKAGE).rglob('*')):
        if source.suffix in ('.py', '.pt', '.onnx') and '__pycache__' not in source.parts:
            rel = source.relative_to(src)
            assert (site[0] / rel).is_file(), f'{rel} is not installed (missing __init__.py or package_data?)'

    # The install, not the repository or the venv's editable copy, is what runs.
    where = subprocess.run(
        [sys.executable, '-c', f'import {PACKAGE}; print({PACKAGE}.__file__)'],
        cwd=colcon_workspace['ws'],
        env=env,
        check=True,
        capture_output=True,
        text=True,
        timeout=60,
    ).stdout.strip()
    assert Path(where).is_relative_to(site[0]), f'{PACKAGE} imported from {where}'


@needs_colcon
def test_ros2_run_agent(colcon_workspace, ros_domain_id, tmp_path, monkeypatch):
    """`ros2 run knode_swarm_ros agent --ros-args -p id:=3`, without the ros2 CLI."""
    from ament_index_python.packages import get_package_prefix

    env = dict(colcon_workspace['sourced_env'])
    env['ROS_DOMAIN_ID'] = str(ros_domain_id)
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    # The ROS wheels' bootstrap variables travel together or not at all.
    assert ('LD_LIBRARY_PATH' in env) or ('_ROS_WHEELS_BOOTSTRAP_COMPLETE' not in env)
    monkeypatch.setenv('AMENT_PREFIX_PATH', env['AMENT_PREFIX_PATH'])
    exe = _executable_path(get_package_prefix(PACKAGE), 'agent')

    log = tmp_path / 'agent.log'
    with open(log, 'wb') as out:
        proc = subprocess.Popen(
            [str(exe), *AGENT_ARGS],
            env=env,
            cwd=tmp_path,
            stdin=subprocess.DEVNULL,
            stdout=out,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
    try:
        # Up when it logs its start-up line (a condition, not a time: loading torch takes from 1 s
        # on a quiet machine to tens of seconds on a loaded one).
        deadline = time.monotonic() + UP_TIMEOUT_S
        while (
            proc.poll() is None
            and time.monotonic() < deadline
            and UP_LINE not in log.read_text(errors='replace')
        ):
            time.sleep(0.1)
        rc = proc.poll()
        output = log.read_text(errors='replace')
        assert rc is not None or UP_LINE in output, f'agent not up after {UP_TIMEOUT_S} s:\n{output}'
        if rc is not None:
            placeholder = rc == PLACEHOLDER_EXIT_CODE and PLACEHOLDER_MESSAGE in output
            assert placeholder, f'agent exited with {rc} before it was up:\n{output}'
            assert ACCEPT_PLACEHOLDER_NODES, f'agent is still the placeholder:\n{output}'
            assert f'{PACKAGE} agent: {PLACEHOLDER_MESSAGE}' in output
            return
        # Up: stop it as Ctrl-C on `ros2 run` would.
        os.killpg(proc.pid, signal.SIGINT)
        try:
            rc = proc.wait(timeout=SHUTDOWN_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            rc = None
        output = log.read_text(errors='replace')
        assert rc is not None, f'agent did not stop on SIGINT:\n{output}'
        assert rc in (0, 130, -signal.SIGINT), f'agent exited with {rc} on SIGINT:\n{output}'
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=10)


def test_venv_is_an_ament_prefix(monkeypatch):
    """`make` installs the package into the venv and copies its data files there."""
    try:
        dist = importlib.metadata.distribution(PACKAGE)
    except importlib.metadata.PackageNotFoundError:
        pytest.skip(f'{PACKAGE} is not installed in {sys.prefix} (run `make venv`)')
    if importlib.util.find_spec('ament_index_python') is None:
        pytest.skip('ament_index_python is not installed (pip install -r requirements.txt)')
    from ament_index_python.packages import PackageNotFoundError, get_package_share_directory

    monkeypatch.setenv('AMENT_PREFIX_PATH', sys.prefix)
    hint = 'run `make venv` to copy the data files into the venv'
    try:
        share = Path(get_package_share_directory(PACKAGE))
    except PackageNotFoundError:
        pytest.fail(f'{PACKAGE} is not in the ament index of {sys.prefix}: {hint}')
    assert share == Path(sys.prefix) / 'share' / PACKAGE
    assert (share / 'package.xml').is_file(), hint
    assert dist.version == '0.1.0'
    for config in sorted((REPO / 'config').rglob('*')):
        if config.is_file():
            rel = config.relative_to(REPO)
            assert (share / rel).is_file(), f'{rel} is not in {share}: {hint}'
