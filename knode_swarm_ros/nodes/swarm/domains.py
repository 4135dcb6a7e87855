"""ROS_DOMAIN_ID claims that concurrent runs on one machine respect.

Two swarms (or two copies of the test suite) that draw the same domain id hear each other's
robots. A claim is an exclusive ``flock`` on ``<tmp>/knode_swarm_ros-domains/<id>.lock``, held
while the claiming object lives (and released by the kernel when its process dies, so a killed
run never leaves a stale claim). Claims only coordinate users of this module; ids used by other
software are not seen. No rclpy import: the launcher and the tests use it.
"""

from __future__ import annotations

import fcntl
import os
import random
import tempfile
from pathlib import Path
from typing import Iterable, Optional

__all__ = ['DomainClaim', 'claim_domain', 'LOCK_DIR']

LOCK_DIR = Path(tempfile.gettempdir()) / 'knode_swarm_ros-domains'


class DomainClaim:
    """A held claim on domain ``domain_id``; :meth:`release` (or process exit) frees it."""

    def __init__(self, domain_id: int, fd: int):
        self.domain_id = int(domain_id)
        self._fd: Optional[int] = fd

    def release(self) -> None:
        if self._fd is not None:
            os.close(self._fd)  # closing the descriptor drops the flock
            self._fd = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.release()
        return False

    def __del__(self):
        self.release()


def _try(domain_id: int) -> Optional[DomainClaim]:
    LOCK_DIR.mkdir(mode=0o777, exist_ok=True)
    try:
        os.chmod(LOCK_DIR, 0o1777)  # shared by every user of the machine, like /tmp
    except OSError:
        pass
    path = LOCK_DIR / f'{int(domain_id)}.lock'
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        return None
    return DomainClaim(domain_id, fd)


def claim_domain(candidates: Iterable[int], rng: Optional[random.Random] = None) -> DomainClaim:
    """Claim one free domain id of ``candidates`` (tried in random order).

    Raises:
        RuntimeError: every candidate is claimed by a live process.
    """
    ids = list(candidates)
    (rng or random.Random()).shuffle(ids)
    for domain_id in ids:
        claim = _try(domain_id)
        if claim is not None:
            return claim
    raise RuntimeError(
        f'every ROS domain id in {min(ids)}..{max(ids)} is claimed by a running process '
        f'(lock files in {LOCK_DIR})'
    )
