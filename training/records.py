"""What a run writes beside its results: JSON written atomically, and the git commit it came from."""
from __future__ import annotations

import json
import subprocess
from typing import Any, Optional

import numpy as np


def write_json(path: str, obj: Any) -> None:
    from knode_swarm_ros.core.trajectory import atomic_write

    def write(tmp):
        with open(tmp, "w") as fh:
            json.dump(obj, fh, indent=2, sort_keys=True, default=_json_default)
            fh.write("\n")
    atomic_write(path, write)


def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def git_commit(cwd: Optional[str] = None) -> Optional[str]:
    """The current git commit (with ``-dirty`` when the tree has changes), or None."""
    try:
        sha = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, cwd=cwd,
                             timeout=5, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], capture_output=True,
                               text=True, cwd=cwd, timeout=5).stdout.strip()
        return sha + ("-dirty" if dirty else "")
    except (OSError, subprocess.SubprocessError):
        return None
