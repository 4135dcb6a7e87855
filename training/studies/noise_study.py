"""Synthetic motion-capture recordings from ground-truth trajectories (docs/noise.md).

A mocap driver publishes geometry_msgs/PoseStamped per robot at a fixed rate; what reaches the bag
differs from the truth by Gaussian position noise, jittered header stamps, dropped messages and
occlusions (a robot unseen for a while). :func:`write_mocap_bag` makes such a bag from one
ground-truth trajectory (``states[T, n, d]`` every ``dt``, as ``python -m training.generate``
writes them), positions taken at the jittered stamps by cubic interpolation of the truth.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Tuple

import numpy as np

from knode_swarm_ros.bag import POSE_STAMPED, BagWriter, ns_to_stamp

__all__ = ['MocapNoise', 'write_mocap_bag', 'truth_at']


@dataclass
class MocapNoise:
    """What the recording adds to the truth."""

    rate: float = 120.0  # Hz, the driver's publishing rate
    noise: float = 0.002  # m, standard deviation of the position noise per axis
    jitter: float = 0.5e-3  # s, standard deviation of the header stamps about the nominal times
    drop: float = 0.01  # fraction of messages lost
    occlusion: Optional[Tuple[int, float, float]] = None  # (robot, start s, duration s) unseen
    latency: float = 2e-3  # s, mean receive delay (the log time); exponential, so some arrive late


def truth_at(states: np.ndarray, dt: float, times: np.ndarray, p: int) -> Tuple[np.ndarray, np.ndarray]:
    """Positions and velocities ``[len(times), n, p]`` of a ground-truth trajectory ``states[T, n, d]``
    (positions then velocities) at ``times`` (s): cubic Hermite between frames from both."""
    T = states.shape[0]
    k = np.clip(np.floor(times / dt).astype(int), 0, T - 2)
    s = (times / dt - k)[:, None, None]
    p0, p1 = states[k, :, :p], states[k + 1, :, :p]
    v0, v1 = states[k, :, p : 2 * p] * dt, states[k + 1, :, p : 2 * p] * dt
    h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2
    pos = h00 * p0 + h10 * v0 + h01 * p1 + h11 * v1
    d00, d10, d01, d11 = 6 * s**2 - 6 * s, 3 * s**2 - 4 * s + 1, -6 * s**2 + 6 * s, 3 * s**2 - 2 * s
    vel = (d00 * p0 + d10 * v0 + d01 * p1 + d11 * v1) / dt
    return pos, vel


def write_mocap_bag(
    path, states: np.ndarray, dt: float, mocap: MocapNoise, rng: np.random.Generator, p: int = 2
) -> dict:
    """Write ``states[T, n, d]`` (positions ``[..., :p]``, velocities ``[..., p:2p]``) as a PoseStamped
    bag on ``/mocap/robot_<i>/pose``, as :class:`MocapNoise` says; the truth of what was written:
    ``{'messages', 'dropped', 'late'}``. Messages enter the bag in receive (log) order."""
    T, n = states.shape[:2]
    nominal = np.arange(0.0, (T - 1) * dt - 2 * mocap.jitter, 1.0 / mocap.rate) + mocap.jitter * 4
    rows = []
    dropped = 0
    for i in range(n):
        t = nominal + rng.normal(0.0, mocap.jitter, nominal.size)
        keep = rng.random(t.size) >= mocap.drop
        dropped += int((~keep).sum())
        if mocap.occlusion is not None and mocap.occlusion[0] == i:
            _, a, d = mocap.occlusion
            keep &= (t < a) | (t > a + d)
        t = t[keep]
        pos, _ = truth_at(states[:, i : i + 1], dt, t, p)
        pos = pos[:, 0] + rng.normal(0.0, mocap.noise, (t.size, p))
        log = t + rng.exponential(mocap.latency, t.size)
        rows.extend((float(lg), float(ts), i, x) for lg, ts, x in zip(log, t, pos))
    rows.sort(key=lambda r: r[0])
    late = 0
    last = {}
    with BagWriter(Path(path)) as bag:
        for log, stamp, i, x in rows:
            late += int(stamp < last.get(i, -1.0))
            last[i] = max(stamp, last.get(i, -1.0))
            stamp_ns = int(round(stamp * 1e9))
            xyz = list(map(float, x)) + [0.0] * (3 - p)
            bag.write(
                f'/mocap/robot_{i}/pose',
                POSE_STAMPED,
                {
                    'header': {'stamp': ns_to_stamp(stamp_ns), 'frame_id': 'world'},
                    'pose': {
                        'position': dict(zip('xyz', xyz)),
                        'orientation': {'x': 0.0, 'y': 0.0, 'z': 0.0, 'w': 1.0},
                    },
                },
                stamp_ns,
                log_time_ns=int(round(log * 1e9)),
            )
    return {'messages': len(rows), 'dropped': dropped, 'late': late}
