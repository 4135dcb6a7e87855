"""The agent's delay buffer: gaps, out-of-order messages, the earliest-state rule."""

import numpy as np
import pytest

from knode_swarm_ros.core import DelayBuffer


def test_out_of_order_messages_are_filed_by_step():
    buf = DelayBuffer(dt=0.1, tau=2)
    for step in (3, 1, 2, 0):
        assert buf.add(7, step * 0.1, [step, 0.0])
    assert [buf.get(7, s)[0] for s in range(4)] == [0, 1, 2, 3]
    assert buf.latest(7)[0] == 3
    np.testing.assert_array_equal(buf.delayed(7, 3), [1, 0])


def test_gaps_are_bridged_by_the_last_state_heard():
    buf = DelayBuffer(dt=0.1)
    buf.add(1, 0.0, [0.0])
    buf.add(1, 0.5, [5.0])
    assert buf.get(1, 3) is None
    assert buf.at(1, 3)[0] == 0.0 and buf.at(1, 7)[0] == 5.0


def test_before_the_first_state_the_earliest_is_used():
    buf = DelayBuffer(dt=0.01, tau=3)
    buf.add(2, 0.05, [5.0])
    buf.add(2, 0.06, [6.0])
    assert buf.delayed(2, 6)[0] == 5.0  # step 3 precedes everything heard
    assert buf.at(9, 0) is None  # never heard


def test_duplicates_keep_the_first_and_stamps_round_to_steps():
    buf = DelayBuffer(dt=0.01)
    assert buf.add(0, 0.0300000001, [1.0])
    assert not buf.add(0, 0.03, [2.0])
    assert buf.get(0, 3)[0] == 1.0


def test_history_is_pruned_behind_the_horizon_but_lookups_still_work():
    buf = DelayBuffer(dt=1.0, tau=2, horizon=5)
    for s in range(100):
        buf.add(0, float(s), [float(s)])
    assert len(buf._steps[0]) <= 7
    assert buf.delayed(0, 99)[0] == 97.0
    assert buf.at(0, 93)[0] == 94.0  # older than the horizon: the earliest kept


def test_forget_and_robots():
    buf = DelayBuffer(dt=0.1)
    buf.add(3, 0.0, [1.0])
    buf.add(1, 0.0, [1.0])
    assert buf.robots() == [1, 3]
    buf.forget(3)
    assert buf.robots() == [1] and buf.latest(3) is None


def test_exactly_the_horizon_plus_the_entry_at_the_cut_is_kept():
    """After every add the history holds exactly steps newest - horizon .. newest (the entry at
    the cut keeps lookups inside the horizon working): not one more, not one fewer."""
    buf = DelayBuffer(dt=1.0, tau=1, horizon=3)
    for s in range(10):
        buf.add(0, float(s), [float(s)])
        kept = [t for t in range(s + 1) if buf.get(0, t) is not None]
        assert kept == list(range(max(0, s - 3), s + 1)), s


def test_a_step_of_zero_or_less_and_a_negative_delay_are_refused():
    for dt in (0.0, -0.1):
        with pytest.raises(ValueError, match='dt must be > 0'):
            DelayBuffer(dt=dt)
    with pytest.raises(ValueError, match='tau must be >= 0'):
        DelayBuffer(dt=0.1, tau=-1)
    assert DelayBuffer(dt=0.1, tau=0).tau == 0


@pytest.mark.parametrize('tau, horizon, kept', [(0, 0, 1), (2, 0, 3), (2, 2, 3), (2, 3, 3), (1, 5, 5)])
def test_the_horizon_is_at_least_tau_plus_one_steps(tau, horizon, kept):
    """History kept behind the newest state: ``max(horizon, tau + 1)`` steps, never fewer."""
    buf = DelayBuffer(dt=1.0, tau=tau, horizon=horizon)
    for s in range(10):
        buf.add(0, float(s), [float(s)])
    assert [t for t in range(10) if buf.get(0, t) is not None] == list(range(9 - kept, 10))
