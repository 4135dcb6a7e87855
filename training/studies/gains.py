"""Why a flock2d controller does or does not scale: its local gains and the large swarm's drift.

    python -m training.studies.gains --policy knode_swarm_ros/policies/flock2d.pt --sizes 10 90 --starts 3 5

Two measurements on held-out ground-truth starts (:func:`core.groundtruth.simulate`, seeds
``--seed`` + n as in :mod:`training.studies.compare_controllers`):

- per-row gains of the controller on ground-truth frames: the mean of d u / d v_row and
  d u / d p_row (trace / 2, central differences) for row 0 (the robot) and every neighbour row.
  The local Tanner law has velocity gains -(k - 1), 1, ..., 1 and position gains that fall with
  the neighbour's distance; a row with gain 0 is a neighbour the controller ignores.
- the disagreement of a rollout from the same starts, fitted by a linear velocity field
  v_i - vbar = A (r_i - rbar): R^2 of the fit, rotation omega = (A_21 - A_12) / 2 and expansion
  rate div = (A_11 + A_22) / 2 (1/s). A swarm that expands at div has avd ~ div x its radius;
  and the number of closed groups of its listening graph (:func:`closed_groups`). The same for
  the observed (ground-truth) swarm, whose global law does not use that graph.

``--add-attraction G`` / ``--add-alignment G`` roll each policy out with G times the local Tanner
law's attraction (its pair term where r > 1) or alignment term added to its command (then
clipped): an intervention that tests whether a missing piece explains a failure.

Shapes: S starts, T frames, n robots, k rows, B = S n matrices.
"""

from __future__ import annotations

import argparse
import sys
from typing import Callable, Dict, List, Optional

import numpy as np

from knode_swarm_ros.core import get_scenario, load_policy, rollout
from knode_swarm_ros.core.cli import cli
from knode_swarm_ros.core.errors import KnodeError
from knode_swarm_ros.core.groundtruth import simulate
from knode_swarm_ros.core.groundtruth.tanner import local_tanner_acceleration
from knode_swarm_ros.core.network import neighbour_index, neighbour_matrices
from knode_swarm_ros.core.saturation import saturate
from training.assessment.scores import final_metrics

Controller = Callable[[np.ndarray, np.ndarray], np.ndarray]  # (Y [B, k, 4], mask [B, k]) -> u [B, 2]


def row_gains(fn: Controller, Y: np.ndarray, mask: np.ndarray, eps: float = 1e-3) -> Dict[str, np.ndarray]:
    """Mean per-row gains ``{"velocity": [k], "position": [k]}`` of ``fn`` at ``Y [B, k, 4]``.

    Entry j is mean_b (d u_x / d Y[b, j, x] + d u_y / d Y[b, j, y]) / 2, for velocities (entries
    2, 3) and positions (entries 0, 1), by central differences of step ``eps``.
    """
    Y = np.asarray(Y, dtype=np.float64)
    out = {}
    for name, first in (('velocity', 2), ('position', 0)):
        gains = []
        for row in range(Y.shape[1]):
            g = np.zeros(len(Y))
            for axis in range(2):
                up, down = Y.copy(), Y.copy()
                up[:, row, first + axis] += eps
                down[:, row, first + axis] -= eps
                g += (np.asarray(fn(up, mask))[:, axis] - np.asarray(fn(down, mask))[:, axis]) / (2 * eps) / 2
            gains.append(g.mean())
        out[name] = np.array(gains)
    return out


def velocity_field(states: np.ndarray) -> Dict[str, float]:
    """Fit v_i - vbar = A (r_i - rbar) to one swarm snapshot ``[n, 4]`` (least squares).

    Returns avd (mean |v_i - vbar|), r2 (the fraction of sum |v_i - vbar|^2 the fit explains),
    omega (rotation rate), div (expansion rate) and radius (mean |r_i - rbar|).
    """
    r = states[:, :2] - states[:, :2].mean(axis=0)
    v = states[:, 2:] - states[:, 2:].mean(axis=0)
    At, *_ = np.linalg.lstsq(r, v, rcond=None)  # v = r @ At, A = At.T
    A = At.T
    total = float((v * v).sum())
    res = v - r @ At
    return {
        'avd': float(np.linalg.norm(v, axis=1).mean()),
        'r2': 1.0 - float((res * res).sum()) / total if total > 0 else 1.0,
        'omega': float(A[1, 0] - A[0, 1]) / 2,
        'div': float(A[0, 0] + A[1, 1]) / 2,
        'radius': float(np.linalg.norm(r, axis=1).mean()),
    }


def closed_groups(states: np.ndarray, d_cr: float, k: int) -> int:
    """Groups of robots that listen only to each other in one snapshot ``[n, 4]``.

    The listening graph has an edge i -> j when j is one of i's k - 1 nearest robots within d_cr
    (the rows of i's neighbour matrix). A closed group is a strongly connected component with no
    edge leaving it: its robots never hear anyone outside it, so a swarm with more than one such
    group cannot reach one velocity under any controller of this information network.
    """
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import connected_components

    n = len(states)
    index, valid = neighbour_index(states, 2, d_cr, k)  # the rows of each robot's neighbour matrix
    rows = np.repeat(np.arange(n), index.shape[1])[valid.ravel()]
    graph = csr_matrix((np.ones(len(rows)), (rows, index[valid])), shape=(n, n))
    count, label = connected_components(graph, directed=True, connection='strong')
    leaves = np.ones(count, bool)
    src, dst = graph.nonzero()
    leaves[label[src][label[src] != label[dst]]] = False
    return int(leaves.sum())


def _still(Y: np.ndarray) -> np.ndarray:
    """``Y`` with every velocity 0: what is left of the local Tanner law is its pair (position) term."""
    out = np.array(Y, dtype=np.float64)
    out[..., 2:] = 0.0
    return out


def tanner_attraction(Y: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``[B, 2]`` the local Tanner pair term -2 (1/r^2 - 1/r^4) r_ij over the masked rows with r > 1
    (where it attracts), from the core's :func:`local_tanner_acceleration`."""
    far = np.asarray(mask, bool) & (np.sum((Y[:, :, :2] - Y[:, :1, :2]) ** 2, axis=-1) > 1.0)
    far[:, 0] = np.asarray(mask, bool)[:, 0]
    return local_tanner_acceleration(_still(Y), far)


def tanner_alignment(Y: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``[B, 2]`` the local Tanner alignment term -sum_j (v_i - v_j) over the masked rows."""
    return local_tanner_acceleration(Y, mask) - local_tanner_acceleration(_still(Y), mask)


def with_terms(fn: Controller, attraction: float, alignment: float, limit: Optional[float]) -> Controller:
    """``fn`` plus ``attraction`` x :func:`tanner_attraction` + ``alignment`` x :func:`tanner_alignment`, clipped."""
    if attraction == 0 and alignment == 0:
        return fn

    def wrapped(Y, m):
        u = np.asarray(fn(Y, m)) + attraction * tanner_attraction(Y, m) + alignment * tanner_alignment(Y, m)
        return saturate(u, limit)

    return wrapped


def _controllers(policies: List[str], limit: float) -> Dict[str, Controller]:
    import torch

    out: Dict[str, Controller] = {'local_tanner': lambda Y, m: local_tanner_acceleration(Y, m, limit)}
    for path in policies:
        module = torch.jit.load(path, map_location='cpu').double()

        def fn(Y, m, module=module):
            with torch.no_grad():
                return module(
                    torch.from_numpy(np.asarray(Y, np.float64)), torch.from_numpy(np.asarray(m))
                ).numpy()

        out[path] = fn
    return out


def _report(
    n: int, name: str, pred: np.ndarray, frames: List[int], count: int, d_cr: float, k: int, dt: float
) -> None:
    """Print the final avd / amd of runs ``[S, T, n, 4]`` and their velocity field at ``frames``."""
    final = final_metrics(get_scenario('flock2d'), pred, dt=dt)
    a = np.array(final['avd_final'])
    print(
        f'n={n} {name}: final avd {a.mean():.3f} ± {a.std(ddof=1) if count > 1 else 0.0:.3f} sd '
        f'[{a.min():.3f}, {a.max():.3f}] amd {np.mean(final["amd_final"]):.3f}',
        flush=True,
    )
    for f in frames:
        fits = [
            dict(velocity_field(pred[s, f]), groups=closed_groups(pred[s, f], d_cr, k)) for s in range(count)
        ]
        col = {key: np.array([x[key] for x in fits]) for key in fits[0]}
        print(
            f'n={n} {name}: rollout t={f * dt:g}s avd {col["avd"].mean():.3f} field R2 '
            f'{col["r2"].mean():.2f} omega {col["omega"].mean():+.3f} div {col["div"].mean():+.3f} '
            f'(per start {np.round(col["div"], 3).tolist()}) radius {col["radius"].mean():.2f} '
            f'closed groups {col["groups"].astype(int).tolist()}',
            flush=True,
        )


@cli('python -m training.studies.gains')
def main(argv: Optional[List[str]] = None) -> int:
    parser = argparse.ArgumentParser(
        prog='python -m training.studies.gains', description=__doc__.split('\n\n')[0]
    )
    parser.add_argument('--policy', action='append', required=True, help='flock2d policy file (repeatable)')
    parser.add_argument('--sizes', type=int, nargs='+', default=[10, 90])
    parser.add_argument(
        '--starts', type=int, nargs='+', default=[3, 5], help='starts per size (one per size)'
    )
    parser.add_argument('--steps', type=int, default=2000)
    parser.add_argument(
        '--frames',
        type=int,
        nargs='+',
        default=[500, 1000, 2000],
        help="frames where gains (first two) and the rollout's field are measured",
    )
    parser.add_argument('--seed', type=int, default=50000, help='start seeds are SEED + n')
    parser.add_argument(
        '--add-attraction',
        type=float,
        default=0.0,
        metavar='G',
        help="add G x the local Tanner attraction to every policy's command",
    )
    parser.add_argument(
        '--add-alignment',
        type=float,
        default=0.0,
        metavar='G',
        help="add G x the local Tanner alignment to every policy's command",
    )
    args = parser.parse_args(argv)
    import torch

    torch.set_num_threads(1)
    if len(args.starts) != len(args.sizes):
        raise KnodeError(f'--starts {args.starts}: one count per size of --sizes {args.sizes}')
    if max(args.frames) > args.steps or min(args.frames) < 0:
        raise KnodeError(f'--frames {args.frames}: frames must lie in 0..--steps ({args.steps})')
    policies = {path: load_policy(path) for path in args.policy}
    first = next(iter(policies.values()))
    if first.scenario != 'flock2d':
        raise KnodeError(f'--policy {args.policy[0]}: gains are defined for flock2d policies only')
    limit = first.meta.get('command_limit')
    k, d_cr, tau, dt = first.k, first.d_cr, first.tau, first.dt
    fns = {
        name: fn if name == 'local_tanner' else with_terms(fn, args.add_attraction, args.add_alignment, limit)
        for name, fn in _controllers(args.policy, limit).items()
    }
    for n, count in zip(args.sizes, args.starts):
        truth = simulate('flock2d', count, n, args.steps + 1, args.seed + n, progress=False)
        _report(n, 'ground_truth', truth, args.frames, count, d_cr, k, dt)
        for name, fn in fns.items():
            for f in args.frames[:2]:
                Y, m = neighbour_matrices(truth[:, [f]], 2, d_cr, k, tau)
                g = row_gains(fn, Y.reshape(-1, k, 4), m.reshape(-1, k))
                print(
                    f'n={n} {name}: truth frame {f} gains velocity {np.round(g["velocity"], 2).tolist()} '
                    f'position {np.round(g["position"], 2).tolist()}',
                    flush=True,
                )
            with np.errstate(all='ignore'):
                pred = rollout(fn, truth[:, 0], args.steps, 'flock2d', d_cr, k, tau, dt)
            _report(n, name, pred, args.frames, count, d_cr, k, dt)
    return 0


if __name__ == '__main__':
    sys.exit(main())
