"""The launcher's own console lines: ``[swarm   12.3 s] ...`` (time since the launcher started)."""

from __future__ import annotations

import time

_T0 = time.monotonic()


def say(text: str) -> None:
    print(f'[swarm {time.monotonic() - _T0:6.1f} s] {text}', flush=True)
