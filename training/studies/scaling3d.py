"""The paper's 3D scaling study: a boids3d policy at 10 to 90 boids in the fixed ±5 cube.

    python -m training.evaluate --policy knode_swarm_ros/policies/boids3d_unity.pt --preset published \\
        --out out/scaling3d_unity --scaling --sizes 10 20 30 40 50 60 70 80 90 --ics 15 --scaling-steps 1700

:func:`training.assessment.evaluation.scaling_study` hands boids3d policies to
:func:`training.assessment.scaling.scaling_study`. Per size n:
``ics`` spawns of the ground truth (:func:`knode_swarm_ros.core.groundtruth.simulate`: the Unity
spawn, uniform in the ball of radius 5 inside the ±5 cube, 10 frames discarded; the boids are
decentralised, so they are the reference at every size), the policy rolled out from each first
frame (:func:`knode_swarm_ros.core.rollout`, all starts at once), and per start:

* ``amd_final`` / ``truth_amd_final``: amd over the last 10 frames;
* ``pod_kld``: KL(truth || policy) of the POD energies (10 modes);
* ``escaped`` / ``truth_escaped``: fraction of the boids that leave the cube (:func:`training.assessment.scaling.leaving`:
  inside in some frame, outside in a later one; a boid spawned outside has not left);
  ``starts_inside``: starts in which no boid leaves (the goal's count);
* ``subswarms`` / ``truth_subswarms``: connected groups (boids linked within the boids' perception
  radius 2.5, transitively), mean over the last 10 frames;
* every escape of a learnt boid (:func:`training.assessment.scaling.escape_events`): when, through which wall, how many
  neighbours it sensed (within d_cr) and how large its group was just before it left.

Writes ``scaling.png`` (box plots) and ``departures.png`` (subswarms and escapes over time, the
final frame of the start with most subswarms at the largest size) into ``out``.
"""

from __future__ import annotations

import os
from typing import Optional, Sequence

from knode_swarm_ros.core.cli import cli
from knode_swarm_ros.core.errors import KnodeError
from training.assessment.scaling import draw, merge, summary_lines


@cli('python -m training.studies.scaling3d')
def main(argv: Optional[Sequence[str]] = None) -> int:
    """``python -m training.studies.scaling3d --merge A/results.json B/results.json --out DIR``: one study from
    ``training.evaluate --scaling`` runs of one policy at different sizes (run in parallel)."""
    import argparse
    import json

    from training.learning.records import write_json

    parser = argparse.ArgumentParser(
        prog='python -m training.studies.scaling3d', description=main.__doc__.split('\n')[0]
    )
    parser.add_argument(
        '--merge', nargs='+', required=True, help='results.json files of training.evaluate --scaling'
    )
    parser.add_argument('--out', required=True)
    args = parser.parse_args(argv)
    runs = []
    for path in args.merge:
        try:
            with open(path) as fh:
                runs.append(json.load(fh))
        except (OSError, ValueError) as exc:
            raise KnodeError(f'--merge {path}: not a readable results.json ({exc})') from None
    policies = {r.get('policy') for r in runs}
    if len(policies) != 1:
        raise KnodeError(f'--merge: the results come from different policies: {sorted(map(str, policies))}')
    missing = [path for path, r in zip(args.merge, runs) if 'scaling' not in r]
    if missing:
        raise KnodeError(
            f"--merge: {', '.join(missing)} hold no 'scaling' results (training.evaluate --scaling)"
        )
    merged = merge([r['scaling'] for r in runs])
    os.makedirs(args.out, exist_ok=True)
    write_json(
        os.path.join(args.out, 'results.json'), {**runs[0], 'scaling': merged, 'merged_from': args.merge}
    )
    draw(merged, args.out)
    lines = ['# Scaling study: boids3d', '', f'- policy: `{policies.pop()}`', ''] + summary_lines(merged)
    with open(os.path.join(args.out, 'summary.md'), 'w') as fh:
        fh.write('\n'.join(lines + ['Figures: scaling.png, departures.png', '']))
    print(f'wrote {args.out}/results.json, summary.md and figures')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
