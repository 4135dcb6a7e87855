"""Comparison statistics on synthetic swarms with known answers."""

import numpy as np
import pytest

from training.assessment.boids_stats import alignment, flockmates, speeds, subgroups, summary, wall_distance


def frame(positions, headings=None):
    p = np.asarray(positions, dtype=float)
    h = np.tile([1.0, 0.0, 0.0], (len(p), 1)) if headings is None else np.asarray(headings, dtype=float)
    return np.concatenate([p, h], axis=1)


def test_speeds_of_constant_motion():
    T, v = 5, np.array([3.0, 4.0, 0.0])
    states = np.stack([frame([t * v / 60, t * v / 60 + 1]) for t in range(T)])
    np.testing.assert_allclose(speeds(states, 1 / 60), 5.0)


def test_flockmates_and_subgroups_of_two_clusters():
    # Two chains: 0-1-2 linked by 2.0 steps (2.5 radius), 3-4 far away; 2 and 0 are 4 apart.
    states = frame([[0, 0, 0], [2, 0, 0], [4, 0, 0], [0, 4, 4], [0, 4, 3]])[None]
    np.testing.assert_array_equal(flockmates(states)[0], [1, 2, 1, 1, 1])
    assert subgroups(states)[0] == 2
    lone = frame([[0, 0, 0], [3, 0, 0], [0, 3, 0], [0, 0, 3]])[None]
    assert subgroups(lone)[0] == 4


def test_alignment_is_mean_cosine_with_flockmates():
    h = [[1, 0, 0], [0, 1, 0], [1, 0, 0], [0, 0, 1]]
    states = frame([[0, 0, 0], [1, 0, 0], [0, 1, 0], [-4, -4, -4]], h)[None]
    a = alignment(states)[0]
    # Boid 0 sees 1 (cos 0) and 2 (cos 1): 0.5; boid 1 sees 0 and 2 (both cos 0): 0; boid 3 alone: NaN.
    np.testing.assert_allclose(a[:3], [0.5, 0.0, 0.5])
    assert np.isnan(a[3])


def test_wall_distance():
    states = frame([[0, 0, 0], [4.5, -1, 2], [-3, -4.9, 0]])[None]
    np.testing.assert_allclose(wall_distance(states)[0], [5.0, 0.5, 0.1])


def test_summary_of_two_known_runs():
    # Run 0: 3 boids in a row 1 apart moving along +x at 3; run 1: 2 apart at 6. Same headings.
    T, dt = 20, 1 / 60
    runs = []
    for gap, v in ((1.0, 3.0), (2.0, 6.0)):
        runs.append(np.stack([frame([[t * v * dt + i * gap, 0, 0] for i in range(3)]) for t in range(T)]))
    s = summary(np.stack(runs), dt, modes=3)
    expect = {
        'speed_mean': (3.0, 6.0),
        'speed_p05': (3.0, 6.0),
        'speed_p95': (3.0, 6.0),
        'alignment': (1.0, 1.0),
        'flockmates': (2.0, 4 / 3),
        'subgroups_final': (1.0, 1.0),
        'amd': (1.0, 2.0),
        # every boid is at y = z = 0 with x >= 0: its closest wall is +x, 5 - x away
        'wall_distance': tuple(
            np.mean([5 - (t * v * dt + i * g) for t in range(T) for i in range(3)])
            for g, v in ((1.0, 3.0), (2.0, 6.0))
        ),
    }
    for key, (a, b) in expect.items():
        assert s[key]['mean'] == pytest.approx((a + b) / 2, rel=1e-9), key
        assert s[key]['std'] == pytest.approx(abs(a - b) / 2, rel=1e-9, abs=1e-12), key
    assert s['runs'] == 2 and sum(s['pod_energy']) == pytest.approx(1.0)


def test_summary_has_every_statistic():
    rng = np.random.default_rng(0)
    states = np.concatenate([rng.uniform(-3, 3, (2, 60, 6, 3)), np.tile([1.0, 0, 0], (2, 60, 6, 1))], axis=-1)
    s = summary(states, 1 / 60)
    assert s['runs'] == 2 and len(s['pod_energy']) == 10
    assert sum(s['pod_energy']) == pytest.approx(1.0)
    for key in ('speed_mean', 'alignment', 'flockmates', 'subgroups_final', 'wall_distance', 'amd'):
        assert np.isfinite(s[key]['mean'])
