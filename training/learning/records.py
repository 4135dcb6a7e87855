"""What a run writes beside its results: JSON written atomically, and the git commit it came from."""

from __future__ import annotations

import json
import os
import subprocess
from typing import Any, Optional

import numpy as np


def write_json(path: str, obj: Any, indent: int = 2, sort_keys: bool = True) -> None:
    """``obj`` as JSON at ``path`` (numpy scalars and arrays as numbers and lists), atomically:
    a crash leaves the old file or the new one, never half of one."""
    from knode_swarm_ros.core.trajectory import atomic_write

    def write(tmp):
        with open(tmp, 'w') as fh:
            json.dump(obj, fh, indent=indent, sort_keys=sort_keys, default=_json_default)
            fh.write('\n')

    atomic_write(path, write)


def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f'not JSON serialisable: {type(o).__name__}')


def git_commit(cwd: Optional[str] = None) -> Optional[str]:
    """The current git commit (with ``-dirty`` when the tree has changes), or None."""
    try:
        sha = subprocess.run(
            ['git', 'rev-parse', 'HEAD'], capture_output=True, text=True, cwd=cwd, timeout=5, check=True
        ).stdout.strip()
        dirty = subprocess.run(
            ['git', 'status', '--porcelain', '--untracked-files=no'],
            capture_output=True,
            text=True,
            cwd=cwd,
            timeout=5,
        ).stdout.strip()
        return sha + ('-dirty' if dirty else '')
    except (OSError, subprocess.SubprocessError):
        return None


def repo_root(cwd: Optional[str] = None) -> Optional[str]:
    """Top directory of the git checkout holding ``cwd`` (default: this code's), or None."""
    cwd = cwd or os.path.dirname(os.path.abspath(__file__))
    try:
        return (
            subprocess.run(
                ['git', 'rev-parse', '--show-toplevel'],
                capture_output=True,
                text=True,
                cwd=cwd,
                timeout=5,
                check=True,
            ).stdout.strip()
            or None
        )
    except (OSError, subprocess.SubprocessError):
        return None


def data_reference(path: str, root: Optional[str] = None) -> str:
    """How provenance names a data file: relative to the repository root when the file lies
    inside the checkout (``data/flock2d.npz``), else relative to the current directory, so no
    machine's absolute layout ends up in a shipped file. ``root`` defaults to :func:`repo_root`."""
    full = os.path.realpath(path)
    root = repo_root() if root is None else root
    if root:
        real_root = os.path.realpath(root)
        if full == real_root or full.startswith(real_root + os.sep):
            return os.path.relpath(full, real_root).replace(os.sep, '/')
    return os.path.relpath(os.path.abspath(path), os.getcwd()).replace(os.sep, '/')


def code_provenance() -> dict:
    """``git_commit`` (``-dirty`` when tracked files differ from it) and ``git_tree_clean`` of the
    checkout holding this code: a shipped policy should name the commit of a clean tree."""
    commit = git_commit(os.path.dirname(os.path.abspath(__file__)))
    return {'git_commit': commit, 'git_tree_clean': bool(commit) and not commit.endswith('-dirty')}
