"""A trained policy with its knowledge terms changed and its network kept: an evaluation-time ablation.

    python -m training.studies.knowledge_variant knode_swarm_ros/policies/boids3d_unity.pt --set collision_d0=0.5 \\
        --out out/ablation/unity_d0_0.5.pt

The Unity-trained policy's spacing piles up just below the collision term's range d0 = 1 at 90
boids. Changing d0 (or switching the term off) in the trained policy, with the
network's parameters and the learnt gains untouched, tells whether the knowledge term sets that
floor: if it does, the spacing follows d0. The result is not a trained model (the network was
fitted with the original term) and says so in ``knode.json`` -> ``provenance.knowledge_variant``.
"""

from __future__ import annotations

import argparse
import os
from typing import Any, Dict, List, Optional

from knode_swarm_ros.core import KNODEPolicy, PolicyConfig, export_policy, load_policy
from knode_swarm_ros.core.cli import cli
from knode_swarm_ros.core.errors import KnodeError
from training.learning.records import code_provenance

#: The knowledge settings this tool may change (PolicyConfig fields that hold no parameters).
CHANGEABLE = {'collision': bool, 'collision_d0': float, 'wall': bool, 'wall_d0': float, 'potential': str}


def parse_changes(items: List[str]) -> Dict[str, Any]:
    """``["collision_d0=0.5", "collision=false"]`` -> ``{"collision_d0": 0.5, "collision": False}``."""
    changes: Dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition('=')
        if not sep or key not in CHANGEABLE:
            raise KnodeError(f'--set {item!r}: expected KEY=VALUE with KEY one of {", ".join(CHANGEABLE)}')
        if CHANGEABLE[key] is bool:
            if value.lower() not in ('true', 'false'):
                raise KnodeError(f'--set {item!r}: {key} takes true or false')
            changes[key] = value.lower() == 'true'
        elif CHANGEABLE[key] is str:
            changes[key] = value  # PolicyConfig names a bad one
        else:
            try:
                changes[key] = float(value)
            except ValueError:
                raise KnodeError(f'--set {item!r}: {key} takes a number') from None
    return changes


def knowledge_variant(loaded, changes: Dict[str, Any]) -> KNODEPolicy:
    """The loaded policy (:func:`load_policy`) rebuilt with ``changes`` to its knowledge settings and
    its own parameters (network and learnt gains)."""
    try:
        config = PolicyConfig(**{**loaded.meta['config'], **changes})  # validates d0 > 0
    except ValueError as exc:
        raise KnodeError(f'--set: {exc}') from None
    policy = KNODEPolicy(config)
    policy.load_state_dict(loaded.module.state_dict())
    return policy


@cli('python -m training.studies.knowledge_variant')
def main(argv: Optional[List[str]] = None) -> int:
    parser = argparse.ArgumentParser(
        prog='python -m training.studies.knowledge_variant', description=__doc__.split('\n\n')[0]
    )
    parser.add_argument('policy')
    parser.add_argument(
        '--set',
        action='append',
        default=[],
        metavar='KEY=VALUE',
        help=f'knowledge setting to change: {", ".join(CHANGEABLE)}',
    )
    parser.add_argument('--out', required=True)
    args = parser.parse_args(argv)
    changes = parse_changes(args.set)
    if not changes:
        raise KnodeError('--set: give at least one change')
    loaded = load_policy(args.policy)  # PolicyError names the file
    policy = knowledge_variant(loaded, changes)
    meta = loaded.meta
    out = policy.metadata(dt=meta['dt'])
    out['provenance'] = {
        **meta.get('provenance', {}),
        'knowledge_variant': {
            'of': os.path.basename(args.policy),
            'changes': changes,
            'note': 'network and gains unchanged, not retrained',
            **code_provenance(),
        },
    }
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    export_policy(policy, args.out, out)
    print(f'wrote {args.out}: {os.path.basename(args.policy)} with {changes}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
