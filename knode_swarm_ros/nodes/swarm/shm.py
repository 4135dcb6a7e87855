"""FastDDS shared-memory cleanup after the launcher's processes have ended.

With ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` this rmw_fastrtps always adds its
shared-memory transport (an XML profile or FASTDDS_BUILTIN_TRANSPORTS does not remove it,
measured), so processes create ``/dev/shm/fastrtps_*`` files; they remove them on a clean exit,
a killed process leaves them behind. The launcher deletes the FastDDS files that appeared during
the run and that no live process holds a lock on (the rule ``fastdds shm clean`` uses, extended
to the ports a killed process leaves without a lock file), so nothing of another user's live
processes is touched.
"""

from __future__ import annotations

import fcntl
import os
import re
from pathlib import Path
from typing import Dict, List, Optional, Set, Tuple

__all__ = [
    'SHM_DIR',
    'SHARED_PORTS',
    'shm_snapshot',
    'shm_cleanup',
    'shm_held_by',
    'shm_lock_holders',
    'shm_left_by',
    'lock_held',
]

SHM_DIR = Path('/dev/shm')
#: Ports outside every domain's range that all participants open (any domain, any user).
SHARED_PORTS = ('fastrtps_port7000', 'fastrtps_port7001')
_SHM_RE = re.compile(r'^(sem\.)?(fastrtps|fastdds)_')


def shm_snapshot() -> set:
    """Names of the FastDDS files in /dev/shm now."""
    try:
        return {n for n in os.listdir(SHM_DIR) if _SHM_RE.match(n)}
    except OSError:
        return set()


def lock_held(path: Path) -> bool:
    """Whether a live process holds the lock of the FastDDS lock file ``path``."""
    try:
        with open(path, 'ab') as fh:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return False
    except OSError:
        return True


def shm_cleanup(before: set) -> List[str]:
    """Delete FastDDS files that appeared since ``before`` and that no live process holds, and
    the :data:`SHARED_PORTS` that no live process holds.

    A segment or port ``X`` comes with a lock file ``X_el`` (or ``X_sl``) that its live owner
    keeps locked, and a port with ``sem.X_mutex``. A group whose lock file is unlocked (its
    owner was killed: the rule of ``fastdds shm clean``) or gone (a port that a killed process
    had opened stays behind after its owner's clean exit, measured) is deleted, but only the
    files of it that are new. Returns the names removed.
    """
    new = shm_snapshot() - before
    bases = set()
    for name in new:
        if name.startswith('sem.') and name.endswith('_mutex'):
            bases.add(name[4:-6])
        elif name.endswith(('_el', '_sl')):
            bases.add(name[:-3])
        else:
            bases.add(name)
    # The ports every domain's participants open stay behind whenever any of their users was
    # killed, so they are usually there before the run already (another run's kill): judged by
    # their lock alone, whoever created them.
    now = shm_snapshot()
    shared = {base for base in SHARED_PORTS if base in now or f'sem.{base}_mutex' in now}
    removed = []
    for base in sorted(bases | shared):
        locks = [SHM_DIR / f'{base}{tail}' for tail in ('_el', '_sl')]
        if any(lock.exists() and lock_held(lock) for lock in locks):
            continue  # a live process owns it
        for victim in (base, f'{base}_el', f'{base}_sl', f'sem.{base}_mutex'):
            if victim in new or (base in shared and victim in now):
                try:
                    (SHM_DIR / victim).unlink()
                    removed.append(victim)
                except OSError:
                    pass
    return removed


def shm_lock_holders() -> Dict[str, Set[int]]:
    """Each FastDDS lock file (``X_el``, ``X_sl``) in /dev/shm that some process holds a lock on
    now, with the pids holding it, read from /proc/locks."""
    try:
        lines = Path('/proc/locks').read_text().splitlines()
    except OSError:
        return {}
    # (major, minor, inode) as /proc/locks writes them: "1: FLOCK ADVISORY WRITE pid 00:1a:123 0 EOF"
    holders: Dict[Tuple[int, int, int], Set[int]] = {}
    for line in lines:
        fields = line.replace('->', ' ').split()
        if len(fields) >= 6 and fields[4].isdigit() and fields[5].count(':') == 2:
            major, minor, inode = fields[5].split(':')
            holders.setdefault((int(major, 16), int(minor, 16), int(inode)), set()).add(int(fields[4]))
    out: Dict[str, Set[int]] = {}
    for name in shm_snapshot():
        if not name.endswith(('_el', '_sl')):
            continue
        try:
            st = (SHM_DIR / name).stat()
        except OSError:
            continue
        pids = holders.get((os.major(st.st_dev), os.minor(st.st_dev), st.st_ino))
        if pids:
            out[name] = pids
    return out


def shm_held_by(pid: int) -> set:
    """Names of the FastDDS lock files (``X_el``, ``X_sl``) that process ``pid`` holds a lock on
    now, read from /proc/locks: those of its own segment and of the ports it listens on, which a
    clean exit removes (with ``X`` and ``sem.X_mutex``). Files of other processes, a concurrent
    test suite's included, are never among them."""
    return {name for name, pids in shm_lock_holders().items() if pid in pids}


_PORT_RE = re.compile(r'^fastrtps_port(\d+)$')


def shm_left_by(held: set, domain: Optional[int] = None, before: frozenset = frozenset()) -> List[str]:
    """Files of the groups whose lock files ``held`` (:func:`shm_held_by`, taken while the owner
    ran) names that are still in /dev/shm after the owner ended, unless a live process holds the
    group's lock again (a later participant reusing a port).

    A port's segment and mutex stay behind when any process that had opened the port was killed
    (measured), whoever owns it. With ``domain``, a port outside that domain's range (7400 + 250
    * domain + 0..249: e.g. ``fastrtps_port7000``, which every domain's participants open) is
    judged by its lock file alone, so another user's killed process never counts as a leak.
    Files in ``before`` (:func:`shm_snapshot` before the owner started: a port that a killed
    process left earlier, then reused) are not the owner's either."""
    left = []
    for lock in sorted(held):
        base = lock[:-3]
        if (SHM_DIR / lock).exists() and lock_held(SHM_DIR / lock):
            continue
        port = _PORT_RE.match(base)
        if domain is not None and port and not 0 <= int(port.group(1)) - (7400 + 250 * domain) < 250:
            left += [lock] if (SHM_DIR / lock).exists() else []
            continue
        left += [n for n in (base, lock, f'sem.{base}_mutex') if (SHM_DIR / n).exists()]
    return [n for n in left if n not in before]
