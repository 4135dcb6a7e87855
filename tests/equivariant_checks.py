"""What the tests of the equivariant encoder's options share: random swarms as every caller builds
their neighbour matrices, and the check that a neighbour in the robot's own state adds nothing."""

import numpy as np
import torch

from knode_swarm_ros.core import neighbour_matrix


def swarm(scenario, n=10, seed=0, k=8, scale=1.5, d_cr=3.0):
    """``Y [n, k, d]``, ``mask [n, k]`` of ``n`` robots at random (unit headings), rows sorted by
    distance (core.network.neighbour_matrix)."""
    rng = np.random.default_rng(seed)
    z = rng.normal(scale=scale, size=(n, scenario.state_dim))
    if scenario.state == 'position_heading':
        p = scenario.position_dim
        z[:, p:] /= np.linalg.norm(z[:, p:], axis=1, keepdims=True)
    Y, mask = neighbour_matrix(z, z, scenario.position_dim, d_cr, k)
    return torch.tensor(Y, dtype=torch.float32), torch.tensor(mask, dtype=torch.float32)


def assert_a_copy_of_the_robot_adds_nothing(policy, Y, mask):
    """With the means off (the mean channel divides by the count, and so does the own term's mean
    of the hidden units), a copy of the robot appended as the last row leaves ``policy.network``'s
    command as it was. Changes ``policy``'s weights."""
    enc = policy.encoder
    with torch.no_grad():
        enc.pair_out.weight[enc.vectors :].zero_()
        if hasattr(enc, 'own'):
            enc.own[-1].weight.zero_()
            enc.own[-1].bias.zero_()
        with_copy = torch.cat([Y, Y[:, :1]], dim=1)
        torch.testing.assert_close(
            policy.network(with_copy, torch.cat([mask, torch.ones(len(Y), 1)], dim=1)),
            policy.network(Y, mask),
            rtol=1e-5,
            atol=1e-6,
        )
