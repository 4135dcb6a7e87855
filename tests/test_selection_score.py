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


def _own(arena=None):
    from knode_swarm_ros.core.scenarios import scenario_from_dict

    return scenario_from_dict(
        dict(name='own', dimensions=2, state='position', command='velocity', dt=0.1, arena=arena)
    )


ORDERS = dict(
    order_polarisation=[0.9, 0.7],
    truth_order_polarisation=[0.95, 0.95],
    order_rotation=[0.1, 0.3],
    truth_order_rotation=[0.1, 0.1],
)


@pytest.mark.parametrize(
    'metrics, arena, expected',
    [
        # |mean amd - mean truth| / mean truth + |polarisation difference| + |rotation difference|
        (dict(ORDERS, amd_final=[0.5, 0.7], truth_amd_final=[0.5, 0.5]), None, 0.2 + 0.15 + 0.1),
        # a swarm that splits from one start of four: the mean sees it, a median would not
        (
            dict(ORDERS, amd_final=[0.5, 0.5, 0.5, 2.5], truth_amd_final=[0.5] * 4),
            None,
            1.0 + 0.15 + 0.1,
        ),
        # escapes per rollout beyond the ground truth's (none below it)
        (
            dict(
                ORDERS,
                amd_final=[0.5, 0.5],
                truth_amd_final=[0.5, 0.5],
                order_escapes=[2, 0],
                truth_order_escapes=[0, 0],
            ),
            {'half_width': 3.0},
            0.15 + 0.1 + 1.0,
        ),
        (
            dict(
                ORDERS,
                amd_final=[0.5, 0.5],
                truth_amd_final=[0.5, 0.5],
                order_escapes=[0, 0],
                truth_order_escapes=[1, 1],
            ),
            {'half_width': 3.0},
            0.15 + 0.1,
        ),
        (dict(ORDERS, amd_final=[float('inf'), 0.5], truth_amd_final=[0.5, 0.5]), None, math.inf),
    ],
)
def test_any_other_scenario(metrics, arena, expected):
    assert selection_score(_own(arena), metrics) == pytest.approx(expected, rel=1e-12)
