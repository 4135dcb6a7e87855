"""Rewrite the provenance of existing policy files: the data path relative to the repository.

    python -m training.studies.provenance knode_swarm_ros/policies/flock2d.pt --data data/flock2d.npz

Policies trained before the trainer wrote relative paths (training/learning/records.py,
:func:`data_reference`) carry the absolute data path of the machine they were trained on. This
rewrites ``knode.json`` -> ``provenance.data`` of each file to ``--data`` as the repository names
it (relative to the checkout root, else to the current directory), keeps everything else
(the module's parameters, ``git_commit``: the commit the policy was *trained* at), records
the commit of this rewrite under ``provenance.metadata_rewritten_at``, and rewrites the ONNX
twin beside it (its metadata must equal the file's). The policy's commands are unchanged: the
file is loaded back and compared on :func:`training.learning.onnx_twin.check_inputs` before it replaces
the original. Exit status 2 on a bad file.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from typing import Any, Dict, List, Optional

import numpy as np
import torch

from knode_swarm_ros.core import load_policy
from knode_swarm_ros.core.cli import cli
from knode_swarm_ros.core.errors import KnodeError
from knode_swarm_ros.core.trajectory import atomic_write
from training.learning.records import code_provenance, data_reference


def rewrite_provenance(pt_path: str, changes: Dict[str, Any]) -> Dict[str, Any]:
    """Update ``knode.json`` -> ``provenance`` of ``pt_path`` with ``changes`` in place; the
    module is saved back as loaded. Returns the new metadata. Raises KnodeError (exit 2) when
    the file is not a policy or its commands change."""
    before = load_policy(pt_path)  # validates the file (PolicyError names it)
    extra = {'knode.json': ''}
    module = torch.jit.load(pt_path, map_location='cpu', _extra_files=extra)
    meta = json.loads(extra['knode.json'])
    meta.setdefault('provenance', {}).update(changes)
    text = json.dumps(meta, sort_keys=True)

    def write(tmp):
        torch.jit.save(module, tmp, _extra_files={'knode.json': text})
        after = load_policy(tmp)
        from training.learning.onnx_twin import check_inputs

        for name, (Y, mask) in check_inputs(after.meta).items():
            if not np.array_equal(before(Y, mask), after(Y, mask)):
                raise KnodeError(
                    f"{pt_path}: the rewritten policy's commands differ on {name}; nothing written"
                )

    atomic_write(pt_path, write)
    return meta


@cli('python -m training.studies.provenance')
def main(argv: Optional[List[str]] = None) -> int:
    parser = argparse.ArgumentParser(
        prog='python -m training.studies.provenance', description=__doc__.split('\n\n')[0]
    )
    parser.add_argument('policy', metavar='POLICY.pt', help='TorchScript policy file')
    parser.add_argument(
        '--data', required=True, help='the data file it was trained on, as this repository names it'
    )
    parser.add_argument('--no-onnx', action='store_true', help='do not rewrite the ONNX twin beside it')
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    if not os.path.isfile(args.policy):
        raise KnodeError(f'{args.policy}: no such policy file')
    here = code_provenance()
    meta = rewrite_provenance(
        args.policy,
        {
            'data': data_reference(args.data),
            'data_file': os.path.basename(args.data),
            'metadata_rewritten_at': here['git_commit'],
        },
    )
    print(f'rewrote {args.policy}: provenance.data = {meta["provenance"]["data"]}')
    twin = os.path.splitext(args.policy)[0] + '.onnx'
    if not args.no_onnx:
        from training.learning.onnx_twin import export_onnx

        path, errors = export_onnx(args.policy, twin)
        print(f'wrote {path}: max difference to TorchScript {max(errors.values()):.2e}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
