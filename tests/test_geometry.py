"""Distances between robots (knode_swarm_ros/core/geometry.py) against the broadcast formula."""

import numpy as np

from knode_swarm_ros.core.geometry import distances, min_pair_distance, pair_distances


def _broadcast(query, others):
    diff = query[..., :, None, :] - others[..., None, :, :]
    return np.sqrt(np.sum(diff * diff, axis=-1))


def test_distances_are_the_broadcast_sums_bit_for_bit():
    rng = np.random.default_rng(0)
    for p in (1, 2, 3, 4, 7, 8, 9):
        for shape_q, shape_o in (((200,), (200,)), ((3, 40), (3, 50)), ((5,), (2, 6)), ((4, 9), (9,))):
            for dtype in (np.float64, np.float32):
                q = (rng.normal(size=shape_q + (p,)) * 10 ** rng.uniform(-6, 6)).astype(dtype)
                o = (rng.normal(size=shape_o + (p,)) * 10 ** rng.uniform(-6, 6)).astype(dtype)
                got, want = distances(q, o), _broadcast(q, o)
                assert got.dtype == want.dtype and np.array_equal(got, want), (p, shape_q, shape_o, dtype)
    states = rng.normal(size=(6, 10, 4))
    view = states[..., :3]  # a strided view, as the callers pass
    assert np.array_equal(distances(view, view), _broadcast(view, view))
    assert distances(np.zeros((3, 0)), np.zeros((2, 0))).tolist() == [[0.0, 0.0]] * 3


def test_pair_distances_of_known_points():
    x = np.array([[0.0, 0.0], [3.0, 4.0], [0.0, 1.0]])
    assert pair_distances(x).tolist() == [[np.inf, 5.0, 1.0], [5.0, np.inf, 18**0.5], [1.0, 18**0.5, np.inf]]
    assert np.diag(pair_distances(x, exclude_self=False)).tolist() == [0.0] * 3
    assert min_pair_distance(x) == 1.0
