"""Hyper-parameters that depend on the swarm, derived from the data and the scenario
(``config/train_custom.yaml``; docs/scenarios.md, "Learning any scenario").

A config field set to ``auto`` is derived here; an explicit value (in the config or ``--set``)
is used as given. Every derived value comes with the sentence that says how, which the trainer
writes to ``summary.json`` and to the policy's ``knode.json`` (``provenance.derived``).

Inputs are trajectories ``[N, T, n, d]`` at the policy's dt (the file's train split). What is
derived, in order (later rules use earlier values, derived or given):

* ``policy.d_cr``: 3 x the median nearest-neighbour distance (the first three shells of
  neighbours of a lattice); with a row-free encoder (``set``, ``equivariant``), the 99th
  percentile of the distances between robots (at least that): the encoder learns the
  interactions' reach itself;
* ``policy.k``: 1 + the 90th percentile of the number of other robots within d_cr, at least 2
  and at most the smallest swarm's size (``policy.encoder: flat``, whose weights are per row);
  with a row-free encoder (weights independent of k) room for larger, denser swarms than
  the data: 1 + the smaller of the robots within d_cr of a robot of a close-packed lattice
  (hexagonal in 2D, fcc in 3D) at the observed median nearest-neighbour distance and 4 x the
  most robots the data show within d_cr;
* ``policy.command_limit``: 1.5 x the 99th percentile of the implied commands' largest axis
  (|dv / dt| for acceleration, |dp / dt| for velocity commands); floored for a swarm whose
  commands are all zero;
* ``policy.collision_d0``: the 1st percentile of nearest-neighbour distances (closer than the
  observed swarm ever gets, the avoidance term only guards), ``policy.collision_phi`` such that
  the push at d0 / 2 is half the command limit;
* ``policy.wall_d0`` (arena only): the 1st percentile of the robots' distances to the nearest
  wall, at least 2 % of the half width, ``policy.wall_phi`` as for collisions;
* ``policy.position_scale``: the RMS of the offsets to the neighbours within d_cr; with
  ``policy.encoder: equivariant`` (distances enter as log(1 + d / scale)) the median
  nearest-neighbour distance;
  ``policy.velocity_scale``: the RMS of the velocity entries (1 for headings or no velocity);
* ``policy.speed``, ``policy.turn_limit`` (heading states only, :mod:`knode_swarm_ros.core.steering`):
  where the data move at a constant speed (the 1st to 99th percentile of the implied speeds
  within 5 % of their median) the median speed, and 1.5 x the largest turn between the own
  heading and the next command (unbounded if that reaches pi); else unset (the command is free);
* ``noise.variance``: (2 % of the smaller input scale)^2;
* ``augment.rotate``: true without an arena (rotations are a symmetry of the scenario), else false;
  false too where the data turn one way about a coordinate axis (:func:`preferred_senses`: a
  swarm that swirls one way about the vertical, which a rotation would turn away);
* ``policy.axes`` (``equivariant`` only; false for the others, which see the offsets' coordinates):
  true where rotations are no symmetry of the law (``augment.rotate`` false: an arena, or a law
  declared so), the pair terms then see the coordinate axes;
* ``policy.symmetric``: the network averaged over the half turns about the axes (in 3D only those
  that keep the data's preferred senses of rotation: a swarm that turns one way about the
  vertical keeps the half turn about it alone, :func:`senses_of_rotation`): without an arena
  as ``augment.rotate`` (a law with a preferred direction sets that false), with one true (the
  half turns map the arena onto itself); false for ``equivariant`` without an arena (exact under
  every rotation already, or seeing the axes, where the half turn about one preferred axis may stay;
  with ``augment.rotate: false`` and ``policy.axes: false`` it is refused, naming the encoder).
* ``policy.inversion``: true in 3D where the equivariant encoder sees the axes and the half turns
  kept are not all three (a constant along an axis would survive their average and sum, in a
  denser swarm, into a drift): the average then also runs over p -> -p, which keeps every sense
  of rotation; false otherwise.
* ``policy.rank`` (``equivariant`` only; 0 for the others): the most robots the data show within
  d_cr, the largest neighbour rank the pair terms tell apart (farther rows in a denser swarm
  count as that rank).
"""

from __future__ import annotations

import math
from typing import Any, Dict, List, Optional, Sequence, Tuple

import numpy as np

from knode_swarm_ros.core.geometry import pair_distances
from knode_swarm_ros.core.metrics import nearest_neighbour_distance
from knode_swarm_ros.core.policy import ROW_FREE_ENCODERS
from knode_swarm_ros.core.scenarios import Scenario

__all__ = ['AUTO', 'DERIVED_FIELDS', 'derive', 'auto_fields', 'size_caveat']

AUTO = 'auto'
#: The config fields that may be ``auto`` (section.key).
DERIVED_FIELDS = (
    'policy.d_cr',
    'policy.k',
    'policy.command_limit',
    'policy.collision_d0',
    'policy.collision_phi',
    'policy.wall_d0',
    'policy.wall_phi',
    'policy.position_scale',
    'policy.velocity_scale',
    'policy.speed',
    'policy.turn_limit',
    'noise.variance',
    'augment.rotate',
    'policy.axes',
    'policy.symmetric',
    'policy.inversion',
    'policy.rank',
)
# A set-encoder policy is sized (k) for neighbourhoods up to this many times the data's largest.
DENSER = 4
# Speeds whose 1st to 99th percentiles lie within this share of their median are a constant speed
# (resampling a curved track shortens each step by less than 0.1 % at the turns of such laws).
CONSTANT_SPEED = 0.05
# Frames used for the statistics: enough for stable quantiles, cheap on long recordings.
MAX_FRAMES = 4000


def auto_fields(raw: Dict[str, Any]) -> List[str]:
    """The ``section.key`` fields of a raw config set to ``auto``."""
    out = []
    for dotted in DERIVED_FIELDS:
        section, key = dotted.split('.')
        part = raw.get(section)
        if isinstance(part, dict) and part.get(key) == AUTO:  # a section that is no mapping is refused later
            out.append(dotted)
    return out


def _frames(trajectories: Sequence[np.ndarray]) -> List[np.ndarray]:
    """Every file's frames ``[F, n, d]`` (at most MAX_FRAMES per file, evenly spaced)."""
    out = []
    for states in trajectories:
        flat = np.asarray(states, dtype=np.float64).reshape(-1, *states.shape[2:])
        step = max(1, len(flat) // MAX_FRAMES)
        out.append(flat[::step])
    return out


def _rates(trajectories: Sequence[np.ndarray], block: slice, dt: float) -> List[np.ndarray]:
    """The change per second of the state entries ``block`` between consecutive frames, one
    ``[N, T-1, n, len(block)]`` array per file."""
    return [np.diff(np.asarray(states, dtype=np.float64)[..., block], axis=1) / dt for states in trajectories]


def _implied_commands(trajectories: Sequence[np.ndarray], spec: Scenario, dt: float) -> np.ndarray:
    """Largest axis of the command a zero-order hold needs between consecutive frames ``[M]``."""
    block = spec.velocity if spec.command == 'acceleration' else spec.position
    return np.concatenate([np.abs(u).max(axis=-1).ravel() for u in _rates(trajectories, block, dt)])


def lattice_neighbours(dimensions: int, radius: float) -> int:
    """Points of a close-packed lattice of unit spacing (hexagonal in 2D, fcc in 3D) within
    ``radius`` of a lattice point, the point itself excluded."""
    if dimensions == 2:
        basis = np.array([[1.0, 0.0], [0.5, math.sqrt(3) / 2]])
    else:
        basis = np.array([[0.0, 1.0, 1.0], [1.0, 0.0, 1.0], [1.0, 1.0, 0.0]]) / math.sqrt(2)
    reach = int(math.ceil(2 * radius)) + 1
    axis = np.arange(-reach, reach + 1)
    index = np.stack(np.meshgrid(*[axis] * dimensions, indexing='ij'), -1).reshape(-1, dimensions)
    dist = np.linalg.norm(index @ basis, axis=-1)
    return int(((dist > 0) & (dist <= radius + 1e-9)).sum())


def _pair_sample(p: np.ndarray) -> np.ndarray:
    """Distances between distinct robots of frames ``p [F, n, dim]`` (at most ~10^6 pairs)."""
    p = p[:: max(1, p.shape[0] * p.shape[1] ** 2 // 1_000_000)]
    d = np.linalg.norm(p[:, None, :, :] - p[:, :, None, :], axis=-1)
    return d[:, ~np.eye(p.shape[1], dtype=bool)].ravel()


def _gain_phi(limit: float, d0: float) -> float:
    """phi with lambda = phi^2 such that the continuous push lambda (1/d - 1/d0) / d^2 at
    d = d0 / 2 is half the command limit: lambda = limit d0^3 / 8."""
    return math.sqrt(limit * d0**3 / 8.0)


def derive(
    cfg: Dict[str, Any], fields: Sequence[str], trajectories: Sequence[np.ndarray], spec: Scenario, dt: float
) -> Tuple[Dict[str, Any], Dict[str, Dict[str, Any]]]:
    """Fill the ``auto`` ``fields`` of ``cfg`` (changed in place) from ``trajectories``
    (one ``[N, T, n, d]`` array per data file, at the policy's ``dt``).

    Returns the config and ``{field: {'value': v, 'how': sentence}}`` for the derived fields.
    """
    pol = cfg['policy']
    frames = _frames(trajectories)
    pos = [f[..., spec.position] for f in frames]
    nn = np.concatenate([nearest_neighbour_distance(p).ravel() for p in pos])
    record: Dict[str, Dict[str, Any]] = {}

    def put(dotted: str, value: Any, how: str) -> None:
        if dotted not in fields:
            return
        section, key = dotted.split('.')
        cfg[section][key] = value
        record[dotted] = {'value': value, 'how': how}

    median_nn = float(np.median(nn))
    encoder = pol.get('encoder', 'flat')
    row_free = encoder in ROW_FREE_ENCODERS
    if row_free:
        pairs = np.concatenate([_pair_sample(p) for p in pos])
        q99_pair = float(np.quantile(pairs, 0.99))
        put(
            'policy.d_cr',
            round(max(q99_pair, 3.0 * median_nn), 6),
            f'the 99th percentile of the distances between robots ({q99_pair:.4g}), at least 3 x the '
            f'median nearest-neighbour distance ({median_nn:.4g}): the {encoder} encoder sees (almost) the '
            'whole observed swarm and learns how far interactions reach (its inputs hold the distance)',
        )
    else:
        put(
            'policy.d_cr',
            round(3.0 * median_nn, 6),
            f'3 x the median nearest-neighbour distance ({median_nn:.4g})',
        )
    d_cr = float(pol['d_cr'])
    n_min = min(f.shape[1] for f in frames)
    counts = _neighbour_counts(pos, d_cr)
    q90 = float(np.quantile(counts, 0.9))
    seen = int(counts.max())  # the most robots within d_cr: k's room and the rank's cap
    if row_free:
        packed = lattice_neighbours(spec.dimensions, d_cr / median_nn)
        put(
            'policy.k',
            int(min(max(2, 1 + min(packed, DENSER * seen)), 1024)),
            f'1 + the smaller of the {packed} robots within d_cr = {d_cr:.4g} of a robot of a '
            f'close-packed {"hexagonal" if spec.dimensions == 2 else "fcc"} lattice at the median '
            f'nearest-neighbour distance ({median_nn:.4g}) and {DENSER} x the most robots the data show '
            f'within d_cr ({seen}): room for larger, denser swarms than the data (the {encoder} '
            'encoder has no weight per row)',
        )
    else:
        put(
            'policy.k',
            int(min(max(2, 1 + math.ceil(q90)), n_min)),
            f'1 + the 90th percentile of the number of robots within d_cr = {d_cr:.4g} ({q90:g}), '
            f'in [2, {n_min}] (the smallest swarm)',
        )
    u = _implied_commands(trajectories, spec, dt)
    q99 = float(np.quantile(u, 0.99)) if u.size else 0.0
    vel = _velocity_entries(frames, trajectories, spec, dt)
    speed_rms = float(np.sqrt(np.mean(vel**2))) if vel.size else 0.0
    floor = speed_rms or 1.0
    unit = 'acceleration (|dv / dt|)' if spec.command == 'acceleration' else 'velocity (|dp / dt|)'
    put(
        'policy.command_limit',
        round(max(1.5 * q99, 0.1 * floor), 6),
        f'1.5 x the 99th percentile ({q99:.4g}) of the implied {unit} commands, largest axis, '
        f'at least 0.1 x the RMS speed entry ({floor:.4g})',
    )
    limit = float(pol['command_limit'])
    q01 = float(np.quantile(nn, 0.01))
    put(
        'policy.collision_d0',
        round(q01, 6),
        'the 1st percentile of nearest-neighbour distances (the observed swarm is closer less than 1 % of the time)',
    )
    d0 = float(pol['collision_d0'])
    put(
        'policy.collision_phi',
        round(_gain_phi(limit, d0), 6),
        f'lambda = phi^2 = command_limit d0^3 / 8: the push at d0 / 2 is half the command limit ({limit:.4g})',
    )
    if spec.arena is not None:
        wall = np.concatenate([(spec.arena - np.abs(p)).min(axis=-1).ravel() for p in pos])
        q = float(np.quantile(wall, 0.01))
        put(
            'policy.wall_d0',
            round(max(q, 0.02 * spec.arena), 6),
            f'the 1st percentile of the distances to the nearest wall ({q:.4g}), at least 2 % of the half width',
        )
        put(
            'policy.wall_phi',
            round(_gain_phi(limit, float(pol['wall_d0'])), 6),
            'lambda = phi^2 = command_limit wall_d0^3 / 8, as for collisions',
        )
    else:
        put('policy.wall_d0', 1.0, 'unused: the scenario has no arena')
        put('policy.wall_phi', 1.0, 'unused: the scenario has no arena')
    if encoder == 'equivariant':
        put(
            'policy.position_scale',
            round(median_nn or _neighbour_offset_rms(pos, d_cr, median_nn) or 1.0, 6),
            'the median nearest-neighbour distance (the equivariant encoder sees log(1 + distance / '
            "this): resolved at the swarm's own spacing, compressed far away)",
        )
    else:
        put(
            'policy.position_scale',
            round(_neighbour_offset_rms(pos, d_cr, median_nn) or 1.0, 6),
            'the RMS of the offsets to the neighbours within d_cr (the network sees positions / this)',
        )
    if spec.velocity is not None:
        put(
            'policy.velocity_scale',
            round(speed_rms or 1.0, 6),
            'the RMS of the velocity entries (the network sees velocities / this)',
        )
    else:
        put('policy.velocity_scale', 1.0, f'1: the state has no velocity ({spec.state})')
    _derive_steering(put, trajectories, spec, dt)
    scales = [float(pol['position_scale'])]
    if spec.velocity is not None:
        scales.append(float(pol['velocity_scale']))
    std = 0.02 * min(scales)
    put(
        'noise.variance',
        float(f'{std * std:.6g}'),
        f'(2 % of the smaller input scale)^2: std {std:.4g} on every input entry',
    )
    senses = preferred_senses(trajectories, spec, dt)
    if spec.arena is not None:
        put('augment.rotate', False, 'false: the arena breaks rotational symmetry')
    elif senses[0]:
        put(
            'augment.rotate',
            False,
            f'false: {senses[1]}; a rotation would turn that sense away, so rotations are no symmetry '
            'of the law',
        )
    else:
        put(
            'augment.rotate',
            True,
            'true: no arena, rotations are a symmetry of the scenario'
            + (', and the data turn no one way about any axis' if spec.position_dim == 3 else ''),
        )
    rotate = bool(cfg['augment']['rotate'])
    if encoder == 'equivariant':
        put(
            'policy.axes',
            not rotate,
            'false: rotations are a symmetry of the law (augment.rotate)'
            if rotate
            else 'true: rotations are no symmetry of the law (augment.rotate is false): the pair terms see '
            'the coordinate axes',
        )
    else:
        put('policy.axes', False, f"false: the {encoder} encoder sees the offsets' coordinates already")
    averaged = ' (the network is averaged over the half turns about the axes)'
    if spec.arena is not None:
        turn, why = _keep_senses(
            'true: the half turns about the axes map the arena onto itself' + averaged, senses
        )
    elif encoder == 'equivariant':
        if not rotate and not pol.get('axes'):  # it could not learn the law's preferred direction
            raise ValueError(
                "policy.encoder = 'equivariant' is exactly rotation-equivariant without policy.axes, but "
                'augment.rotate is false (a law that rotations change, without an arena): set policy.axes '
                'true (or auto), or use policy.encoder set or flat'
            )
        if rotate:
            turn, why = False, 'false: the equivariant encoder is exactly rotation-equivariant already'
        elif senses[0]:  # the axes are seen: the half turn about a preferred axis alone may stay
            turn, why = _keep_senses('', senses)
        else:
            turn, why = False, 'false: no arena, and the law is no rotation invariant (policy.axes)'
    else:
        turn = rotate
        why = 'as augment.rotate: ' + (
            'the law is taken to be rotation invariant' if turn else 'rotations are off'
        )
        why += averaged
        if turn or senses[0]:  # rotations off for a preferred sense: its own half turn stays
            turn, why = _keep_senses(why, senses)
    put('policy.symmetric', turn, why)
    turn = pol['symmetric']
    if spec.position_dim == 3 and pol.get('axes') and turn is not True:
        put(
            'policy.inversion',
            True,
            'true: the pair terms see the axes and the half turns kept '
            f'({"none" if turn is False else "about " + turn}) leave a constant push along an axis, which a '
            'swarm denser than the data sums into a drift; the inversion p -> -p keeps every sense of '
            'rotation and averages it to zero (the parity the encoder has without the axes)',
        )
    else:
        put(
            'policy.inversion',
            False,
            'false: '
            + (
                'in 2D the half turn is the inversion'
                if spec.position_dim == 2
                else 'the half turns about the three axes average any constant to zero'
                if turn is True
                else 'the encoder does not see the axes (without them the equivariant encoder is odd already)'
            ),
        )
    if encoder == 'equivariant':
        put(
            'policy.rank',
            max(seen, 1),
            f"the most robots the data show within d_cr ({seen}): the pair terms see a neighbour's rank "
            'by distance (a topological law heeds its few nearest), up to the largest rank the data '
            'hold; farther rows in a denser swarm count as that rank',
        )
    else:
        put('policy.rank', 0, f'0: the {encoder} encoder has no rank input')
    return cfg, record


def senses_of_rotation(trajectories: Sequence[np.ndarray], spec: Scenario, dt: float):
    """Each trajectory's mean signed rotation about each coordinate axis: the component along it
    of ``(p - c) x v / (|p - c| |v|)`` (c the swarm's centroid, v from the positions), averaged
    over frames and moving robots. Returns ``[U, 3]`` (3D; ``[0, 3]`` in 2D, where the one half
    turn keeps every sense)."""
    if spec.position_dim != 3:
        return np.zeros((0, 3))
    out = []
    for states, v in zip(trajectories, _rates(trajectories, spec.position, dt)):
        p = np.asarray(states, dtype=np.float64)[:, :-1][..., spec.position]
        r = p - p.mean(axis=-2, keepdims=True)
        norm = np.linalg.norm(r, axis=-1) * np.linalg.norm(v, axis=-1)  # [N, T-1, n]
        moving = norm > 1e-12
        spin = np.cross(r, v) / np.where(moving, norm, 1.0)[..., None]
        out.append(
            (spin * moving[..., None]).sum(axis=(1, 2)) / np.maximum(moving.sum(axis=(1, 2)), 1)[:, None]
        )
    return np.concatenate(out)


def preferred_senses(trajectories: Sequence[np.ndarray], spec: Scenario, dt: float) -> Tuple[List[str], str]:
    """The coordinate axes about which the data turn one way (the mean of :func:`senses_of_rotation`
    over the trajectories beyond 3 standard errors and 0.1), and the sentence that says so; none
    in 2D (a rotation keeps every sense there) or with fewer than three trajectories."""
    spin = senses_of_rotation(trajectories, spec, dt)
    if len(spin) < 3:
        return [], ''
    mean = spin.mean(axis=0)
    se = spin.std(axis=0, ddof=1) / math.sqrt(len(spin))
    preferred = [axis for axis, m, e in zip('xyz', mean, se) if abs(m) > max(3.0 * e, 0.1)]
    if not preferred:
        return [], ''
    said = ', '.join(f'{axis}: {m:+.3g} ± {e:.2g}' for axis, m, e in zip('xyz', mean, se))
    return preferred, (
        f'the data turn one way about {" and ".join(preferred)} (mean signed rotation over {len(spin)} '
        f'trajectories, ± standard error: {said})'
    )


def _keep_senses(why: str, senses: Tuple[List[str], str]):
    """``policy.symmetric`` true (all half turns, said so by ``why``) narrowed to those that keep
    the data's preferred senses (:func:`preferred_senses`): the half turns about the other axes,
    which reverse a sense, are left out: only the one about that axis (one preferred axis) or none
    (more)."""
    preferred, seen = senses
    if not preferred:
        return True, why
    if len(preferred) == 1:
        return preferred[0], (
            f'{preferred[0]}: {seen}; the half turns about the other axes would reverse it: the network is '
            f'averaged over the half turn about {preferred[0]} alone'
        )
    return False, f'false: {seen}; every half turn would reverse one of them'


def _derive_steering(put, trajectories: Sequence[np.ndarray], spec: Scenario, dt: float) -> None:
    """``policy.speed`` and ``policy.turn_limit`` (module docstring) through ``put``."""
    if spec.heading is None:
        for dotted in ('policy.speed', 'policy.turn_limit'):
            put(dotted, None, f'unset: the state has no heading ({spec.state})')
        return
    speeds, turns = [], []
    for states, u in zip(trajectories, _rates(trajectories, spec.position, dt)):
        h = np.asarray(states, dtype=np.float64)[:, :-1][..., spec.heading]
        speed, length = np.linalg.norm(u, axis=-1), np.linalg.norm(h, axis=-1)
        both = (speed > 0) & (length > 0)  # a turn needs a heading and a step
        cos = (u * h).sum(-1)[both] / (speed[both] * length[both])
        speeds.append(speed.ravel())
        turns.append(np.arccos(np.clip(cos, -1.0, 1.0)))
    speed, turn = np.concatenate(speeds), np.concatenate(turns)
    if speed.size == 0 or turn.size == 0:
        for dotted in ('policy.speed', 'policy.turn_limit'):
            put(dotted, None, 'unset: the data have no step between two frames')
        return
    median = float(np.median(speed))
    lo, hi = (float(q) for q in np.quantile(speed, [0.01, 0.99]))
    spread = f'1st to 99th percentile of the implied speeds {lo:.4g} to {hi:.4g}, median {median:.4g}'
    if median <= 0 or max(hi - median, median - lo) > CONSTANT_SPEED * median:
        put('policy.speed', None, f'unset: the speeds vary ({spread}): the command is free')
        put('policy.turn_limit', None, 'unset: a turn limit goes with a set speed')
        return
    put(
        'policy.speed',
        round(median, 6),
        f'the median speed: the data move at a constant speed ({spread}, within '
        f'{CONSTANT_SPEED:.0%}): the network steers the heading (core.steering)',
    )
    largest = float(turn.max())
    limit = 1.5 * largest
    put(
        'policy.turn_limit',
        round(limit, 6) if limit < math.pi else None,
        f'1.5 x the largest turn from the own heading to the next command in the data ({largest:.4g} rad)'
        + ('' if limit < math.pi else ': that reaches pi, so unset (unbounded)'),
    )


def _neighbour_counts(pos: Sequence[np.ndarray], d_cr: float) -> np.ndarray:
    """The number of other robots within ``d_cr`` of each robot in frames ``pos [F, n, dim]``,
    flattened over every file, frame and robot."""
    return np.concatenate([(pair_distances(p) <= d_cr).sum(axis=-1).ravel() for p in pos])


def size_caveat(trajectories: Sequence[np.ndarray], spec: Scenario, d_cr: float) -> Optional[str]:
    """A sentence where the data cannot say how the law scales with the swarm's size, else None.

    With one swarm size n in every file and (almost, 90 % of the robots in the frames) every
    robot seeing all n - 1 others within ``d_cr``, a force summed over the neighbours and one
    averaged over them (or scaled by 1 / n) give the same commands on every sample: which one
    the training picks is arbitrary, and a larger swarm will show it.
    """
    sizes = sorted({int(np.shape(t)[-2]) for t in trajectories})
    if len(sizes) != 1 or sizes[0] < 3:
        return None
    n = sizes[0]
    pos = [f[..., spec.position] for f in _frames(trajectories)]
    counts = _neighbour_counts(pos, d_cr)
    share = float(np.mean(counts >= n - 1))
    if share < 0.9:
        return None
    return (
        f'every robot sees all {n - 1} others within d_cr = {d_cr:.4g} in {100 * share:.0f} % of the '
        f'frames of the one swarm size ({n}) in the data: the data cannot tell a force summed over '
        'the neighbours from one averaged over them, so behaviour at other sizes is a guess; tracks '
        'of a second swarm size (--data a.npz b.npz) can tell them apart'
    )


def _neighbour_offset_rms(pos: Sequence[np.ndarray], d_cr: float, empty: float) -> float:
    """The RMS of the offsets between robots within ``d_cr`` in frames ``pos [F, n, dim]``
    (``empty`` where no two robots are that close)."""
    offsets = []
    for p in pos:
        p = p[:: max(1, p.shape[0] * p.shape[1] ** 2 // 2_000_000)]  # bounded memory for large swarms
        diff = p[:, None, :, :] - p[:, :, None, :]  # [F, n, n, dim]
        dist = np.linalg.norm(diff, axis=-1)
        near = (dist <= d_cr) & (dist > 0)
        offsets.append(diff[near].ravel())
    flat = np.concatenate(offsets)
    return float(np.sqrt(np.mean(flat**2))) if flat.size else empty


def _velocity_entries(frames, trajectories, spec: Scenario, dt: float) -> np.ndarray:
    """Velocity components ``[...]``: the state's, else differences of positions."""
    if spec.velocity is not None:
        return np.concatenate([f[..., spec.velocity].ravel() for f in frames])
    parts = [u.ravel() for u in _rates(trajectories, spec.position, dt)]
    return np.concatenate(parts) if parts else np.zeros(0)
