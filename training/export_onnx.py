"""Export a policy file to its ONNX twin (docs/DESIGN.md, "ONNX twin").

    python -m training.export_onnx POLICY.pt [MORE.pt ...] [--out POLICY.onnx] [--tol 1e-5]

Any valid policy file works, ours or anyone's: the TorchScript module is exported with the
TorchScript-based exporter (``torch.onnx.export(..., dynamo=False)``: it takes a
ScriptModule as it is and needs no onnxscript), inputs ``Y [batch, k, d]`` and
``mask [batch, k]`` with a dynamic batch, output ``u [batch, m]``. The model's metadata
carries the same ``knode.json`` text and the SHA-256 of the ``.pt`` (a stale twin is refused
at load). Before the file is written the twin is run on onnxruntime against the TorchScript
module on :func:`check_inputs` (random rows, empty neighbourhoods, full rows, coincident
robots, robots at and beyond the walls, neighbour matrices of real ground-truth swarms);
a command further than ``tol`` (relative above 1) from TorchScript's fails the export and
writes nothing. Exit status 2 on a bad file.
"""

from __future__ import annotations

import argparse
import sys
from typing import List, Optional

import torch

from knode_swarm_ros.core.cli import cli
from knode_swarm_ros.core.errors import KnodeError
from training.learning.onnx_twin import TOLERANCE, export_onnx


@cli('python -m training.export_onnx')
def main(argv: Optional[List[str]] = None) -> int:
    parser = argparse.ArgumentParser(
        prog='python -m training.export_onnx', description=__doc__.split('\n\n')[0]
    )
    parser.add_argument('policies', nargs='+', metavar='POLICY.pt', help='TorchScript policy file(s)')
    parser.add_argument('--out', help='output file (one policy only; default: POLICY.onnx beside it)')
    parser.add_argument(
        '--tol', type=float, default=TOLERANCE, help='largest allowed difference (default 1e-5)'
    )
    args = parser.parse_args(argv)
    if args.out and len(args.policies) > 1:
        raise KnodeError('--out needs exactly one POLICY.pt')
    if not args.tol > 0:
        raise KnodeError(f'--tol must be > 0, got {args.tol}')
    torch.set_num_threads(1)
    for pt in args.policies:
        path, errors = export_onnx(pt, args.out, args.tol)
        print(
            f'wrote {path}: max difference to TorchScript {max(errors.values()):.2e} '
            f'({", ".join(f"{n} {e:.1e}" for n, e in errors.items())})'
        )
    return 0


if __name__ == '__main__':
    sys.exit(main())
