"""The export contract of a policy module, checked for the tests of each network kind: the
TorchScript file equals the eager module bit for bit, its ONNX twin within 1e-5."""

import numpy as np
import torch

from knode_swarm_ros.core import export_policy, load_policy, load_runtime
from training.learning.onnx_twin import export_onnx


def assert_exports_equal(policy, path, Y, mask):
    """Export ``policy`` to ``path`` with its ONNX twin and check both on ``Y [B, k, d]``,
    ``mask [B, k]``; returns the loaded policy file."""
    export_policy(policy, path, policy.metadata())
    loaded = load_policy(path)
    with torch.no_grad():
        eager = policy(Y, mask)
        assert torch.equal(loaded.module(Y, mask), eager)
    _, errors = export_onnx(path)  # checks the twin on the input table (1e-5)
    assert max(errors.values()) <= 1e-5
    twin = load_runtime(path, runtime='onnxruntime')
    np.testing.assert_allclose(twin(Y.numpy(), mask.numpy()), eager.numpy(), rtol=1e-5, atol=1e-5)
    return loaded
