"""training.assessment.scores.selection_score: known answers (lower is better)."""

import math

import pytest

from knode_swarm_ros.core import get_scenario
from training.assessment.scores import selection_score

FLOCK = dict(avd_final=[0.01, 0.03], min_distance=[0.6, 0.5])


@pytest.mark.parametrize(
    'metrics, expected',
    [
        # mean avd + |median amd - median truth amd| / median truth amd + collisions
        (dict(FLOCK, amd_final=[0.7, 0.7], truth_amd_final=[0.7, 0.7]), 0.02),
        (dict(FLOCK, amd_final=[0.77, 0.77], truth_amd_final=[0.7, 0.7]), 0.02 + 0.1),
        (dict(FLOCK, amd_final=[0.7, 0.7], truth_amd_final=[0.7, 0.7], min_distance=[0.2, 0.5]), 1.02),
        # a start whose ground truth blew apart (amd 90) does not wash out the amd term
        (
            dict(
                avd_final=[0.01] * 3,
                min_distance=[0.6] * 3,
                amd_final=[0.84, 0.84, 0.84],
                truth_amd_final=[0.7, 0.7, 90.0],
            ),
            0.01 + 0.2,
        ),
        (dict(FLOCK, amd_final=[float('nan'), 0.7], truth_amd_final=[0.7, 0.7]), math.inf),
    ],
)
def test_flock2d(metrics, expected):
    assert selection_score(get_scenario('flock2d'), metrics) == pytest.approx(expected, rel=1e-12)


@pytest.mark.parametrize(
    'metrics, expected',
    [
        # |median amd - median truth| / median truth + mean POD-KLD + share of rollouts leaving the cube
        (
            dict(
                amd_final=[1.1, 1.3],
                truth_amd_final=[1.0, 1.0],
                pod_kld=[0.02, 0.04],
                stays_inside=[1.0, 0.0],
            ),
            0.2 + 0.03 + 0.5,
        ),
        (dict(amd_final=[1.0], truth_amd_final=[1.0], pod_kld=[0.01], stays_inside=[1.0]), 0.01),
    ],
)
def test_boids3d(metrics, expected):
    assert selection_score(get_scenario('boids3d'), metrics) == pytest.approx(expected, rel=1e-12)
