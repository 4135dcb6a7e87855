"""Imports point downwards only (docs/DESIGN.md, "Layers"), and where a command may live.

Layers, bottom up: ``knode_swarm_ros/core`` (the paper's maths) <- ``knode_swarm_ros/logic`` (what
robots, the simulated swarm and the recorder decide, no ROS) <- ``knode_swarm_ros/bag`` and
``knode_swarm_ros/nodes`` (ROS 2 plumbing, the only place rclpy is imported) <- ``training/``.
The checks read every module's import statements (top level and inside functions), so a lazy
import counts as much as an eager one.
"""

import ast
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / 'knode_swarm_ros'
TRAINING = ROOT / 'training'
ROS_MODULES = ('rclpy', 'builtin_interfaces', 'rosidl_runtime_py', 'rosgraph_msgs')


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix('').parts)
    return '.'.join(parts[:-1] if parts[-1] == '__init__' else parts)


def _imports(path: Path):
    """Absolute names of every module ``path`` imports (relative imports resolved)."""
    tree = ast.parse(path.read_text(), str(path))
    here = _module_name(path).split('.')
    package = here if path.name == '__init__.py' else here[:-1]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - (node.level - 1)]
                module = '.'.join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ''
            yield module
            for alias in node.names:  # ``from . import x`` imports the module x
                yield f'{module}.{alias.name}'


def _modules(folder: Path):
    return sorted(p for p in folder.rglob('*.py') if '__pycache__' not in p.parts)


def _is_ros(name: str) -> bool:
    top = name.split('.')[0]
    return top in ROS_MODULES or top.endswith('_msgs')


def _violations(folder: Path, allowed):
    """``(file, imported name)`` for every import of the package or training outside ``allowed``."""
    found = []
    for path in _modules(folder):
        for name in _imports(path):
            ours = name.split('.')[0] in ('knode_swarm_ros', 'training')
            if ours and name != 'knode_swarm_ros' and not name.startswith(allowed):
                found.append((str(path.relative_to(ROOT)), name))
    return found


def test_no_rclpy_or_message_package_outside_nodes():
    found = []
    for folder in (PACKAGE, TRAINING):
        for path in _modules(folder):
            if PACKAGE / 'nodes' in path.parents:
                continue
            found += [(str(path.relative_to(ROOT)), n) for n in _imports(path) if _is_ros(n)]
    assert found == []


@pytest.mark.parametrize(
    'layer,allowed',
    [
        ('core', ('knode_swarm_ros.core',)),
        ('logic', ('knode_swarm_ros.core', 'knode_swarm_ros.logic')),
        ('bag', ('knode_swarm_ros.core', 'knode_swarm_ros.logic', 'knode_swarm_ros.bag')),
        (
            'nodes',
            ('knode_swarm_ros.core', 'knode_swarm_ros.logic', 'knode_swarm_ros.bag', 'knode_swarm_ros.nodes'),
        ),
    ],
)
def test_each_layer_imports_only_what_lies_below_it(layer, allowed):
    assert _violations(PACKAGE / layer, allowed) == []


def test_nothing_in_the_package_imports_training():
    found = [(p, n) for p, n in _violations(PACKAGE, ('knode_swarm_ros',)) if n.startswith('training')]
    assert found == []


def test_the_layer_check_sees_a_violation(tmp_path, monkeypatch):
    """The checker itself: an upward import in a module is found."""
    layer = tmp_path / 'knode_swarm_ros' / 'core'
    layer.mkdir(parents=True)
    (layer / 'bad.py').write_text('def f():\n    from ..nodes.common import qos\n    import rclpy\n')
    monkeypatch.setattr(sys.modules[__name__], 'ROOT', tmp_path)
    assert _violations(layer, ('knode_swarm_ros.core',)) == [
        ('knode_swarm_ros/core/bad.py', 'knode_swarm_ros.nodes.common'),
        ('knode_swarm_ros/core/bad.py', 'knode_swarm_ros.nodes.common.qos'),
    ]
    assert [n for n in _imports(layer / 'bad.py') if _is_ros(n)] == ['rclpy']


# -- training/: pipeline commands at the top, libraries grouped by job, studies apart ----------

LIBRARY_FOLDERS = ('data', 'learning', 'assessment')
COMMAND_FOLDERS = (TRAINING, TRAINING / 'studies')


def _has_main(path: Path) -> bool:
    tree = ast.parse(path.read_text(), str(path))
    return any(isinstance(n, ast.FunctionDef) and n.name == 'main' for n in tree.body)


def _commands():
    return {_module_name(p) for folder in COMMAND_FOLDERS for p in folder.glob('*.py') if _has_main(p)}


def test_a_main_lives_only_in_a_command_module():
    libraries = [p for f in LIBRARY_FOLDERS for p in _modules(TRAINING / f)]
    assert libraries, 'no library modules found: the layout changed without this test'
    assert [str(p.relative_to(ROOT)) for p in libraries if _has_main(p)] == []
    assert {'training.train', 'training.evaluate', 'training.generate', 'training.import_bag'} <= _commands()


def test_commands_never_import_commands():
    commands = _commands()
    found = []
    for name in sorted(commands):
        path = ROOT / (name.replace('.', '/') + '.py')
        found += [(name, n) for n in _imports(path) if n in commands and n != name]
    assert found == []


def test_every_command_has_a_help(tmp_path):
    """``python -m training.<command> --help`` prints a usage and exits 0, for every command."""
    names = sorted(_commands())
    code = (
        'import contextlib, importlib, io, sys\n'
        'for name in sys.argv[1:]:\n'
        '    out = io.StringIO()\n'
        '    with contextlib.redirect_stdout(out):\n'
        '        try:\n'
        '            importlib.import_module(name).main(["--help"])\n'
        '        except SystemExit as exc:\n'
        '            assert exc.code in (0, None), (name, exc.code)\n'
        '        else:\n'
        '            raise AssertionError(f"{name} --help did not exit")\n'
        '    assert "usage:" in out.getvalue(), (name, out.getvalue())\n'
    )
    proc = subprocess.run(
        [sys.executable, '-c', code, *names], cwd=ROOT, capture_output=True, text=True, timeout=300
    )
    assert proc.returncode == 0, proc.stderr


# -- nodes/: one folder per executable, nothing happens on import ------------------------------

EXECUTABLES = ('agent', 'agents', 'simulator', 'recorder', 'lifecycle_manager', 'swarm', 'monitor')


@pytest.mark.parametrize('name', EXECUTABLES)
def test_every_executable_is_a_folder_with_a_main_and_a_dunder_main(name):
    folder = PACKAGE / 'nodes' / name
    assert (folder / '__init__.py').is_file() and (folder / '__main__.py').is_file()


def test_importing_the_executables_has_no_side_effects():
    """No rclpy, torch or signal handler comes with importing any executable's package."""
    code = (
        'import importlib, signal, sys\n'
        'before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}\n'
        f'for name in {EXECUTABLES!r}:\n'
        '    importlib.import_module("knode_swarm_ros.nodes." + name)\n'
        'heavy = sorted(m for m in sys.modules if m.split(".")[0] in ("rclpy", "torch"))\n'
        'assert not heavy, heavy\n'
        'assert before == {s: signal.getsignal(s) for s in before}, "signal handlers changed"\n'
    )
    env = {k: v for k, v in os.environ.items() if k != 'PYTHONWARNINGS'}
    proc = subprocess.run(
        [sys.executable, '-c', code], cwd=ROOT, capture_output=True, text=True, timeout=120, env=env
    )
    assert proc.returncode == 0, proc.stderr
