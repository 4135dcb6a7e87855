"""The recorder applies the agents' checks to every stamp (age, step grid,
finiteness), so a hostile or stale message can neither invent frames nor lose the recording."""

import numpy as np
import pytest

from knode_swarm_ros.logic.recorder import FrameCollector, swarm_metrics

DT = 0.01
NS = 1_000_000_000


def _run(fc, steps, every=1, n=3, clock=True):
    """A clean run: every robot at steps 0, every, 2 every, ... stamped exactly."""
    rng = np.random.default_rng(0)
    truth = {}
    for s in range(0, steps + 1, every):
        frame = rng.normal(size=(n, 4))
        truth[s] = frame
        for r in range(n):
            stamp = int(round(s * DT * NS))
            assert fc.receive(r, stamp, frame[r], stamp if clock else None) == 'accepted'
    return truth


def test_a_negative_stamp_is_dropped_and_the_file_is_still_written(tmp_path):
    fc = FrameCollector('flock2d', 3, DT)
    fc.set_every(5)
    truth = _run(fc, 100, every=5)
    # one state stamped -0.03 s, on the dt grid but before the run, off the publishing grid
    assert fc.receive(1, int(-0.03 * NS), np.zeros(4), 100 * int(DT * NS)) == 'too_old'
    states, info = fc.build(5)
    assert info['first_step'] == 0 and states.shape[0] == 21 and info['incomplete_frames'] == 0
    assert np.array_equal(states[-1], truth[100])


def test_stale_stamps_cannot_invent_frames():
    fc = FrameCollector('flock2d', 3, DT)
    truth = _run(fc, 2000)
    for i in range(20):
        assert fc.receive(i % 3, int(-1000 * NS), np.ones(4), 2000 * int(DT * NS)) == 'too_old'
    states, info = fc.build(1)
    assert states.shape[0] == 2001 and info['filled_entries'] == 0
    a, m = swarm_metrics(states[-1], 'flock2d')
    assert (a, m) == swarm_metrics(truth[2000], 'flock2d')
    assert fc.counters['too_old'] == 20


def test_without_a_clock_the_newest_stamp_is_the_reference():
    fc = FrameCollector('flock2d', 2, DT, max_age=5.0)
    _run(fc, 100, n=2, clock=False)
    assert fc.receive(0, int(-1000 * NS), np.ones(4)) == 'too_old'
    assert fc.receive(0, int(1000 * NS), np.ones(4)) == 'too_future'
    assert fc.receive(0, int(0.5 * NS), np.ones(4)) == 'duplicate'  # within the window: filed normally
    assert fc.build(1)[0].shape[0] == 101


@pytest.mark.parametrize(
    'now_ns, expected',
    [(None, 'accepted'), (0, 'accepted'), (-NS, 'accepted'), (1, 'too_future'), (int(9.6 * NS), 'accepted')],
)
def test_any_positive_clock_reading_is_a_clock(now_ns, expected):
    """A state 10 s ahead of an empty recorder: a clock (now_ns > 0, one nanosecond included)
    allows future_tolerance 0.5 s ahead; without one (None or <= 0) nothing is there to compare."""
    fc = FrameCollector('flock2d', 2, DT, max_age=5.0, future_tolerance=0.5)
    assert fc.receive(0, 10 * NS, np.ones(4), now_ns) == expected


def test_future_off_grid_and_non_finite_stamps_are_dropped_and_counted():
    fc = FrameCollector('flock2d', 2, DT, future_tolerance=0.5)
    _run(fc, 10, n=2)
    now = int(0.1 * NS)
    assert fc.receive(0, int(1000 * NS), np.ones(4), now) == 'too_future'
    assert fc.receive(0, int(0.115 * NS), np.ones(4), now) == 'off_grid'
    assert fc.receive(0, int(0.11 * NS), np.array([np.nan, 0, 0, 0]), now) == 'non_finite'
    assert fc.counters['too_future'] == fc.counters['off_grid'] == fc.counters['non_finite'] == 1
    assert fc.build(1)[0].shape[0] == 11


def test_a_stray_frame_off_the_publishing_grid_does_not_shift_the_grid(tmp_path):
    fc = FrameCollector('flock2d', 3, DT)
    fc.set_every(5)
    truth = _run(fc, 50, every=5)
    # a legal stamp (on the dt grid, in the clock window) but at step 2, off the every-5 grid
    assert fc.receive(0, int(0.02 * NS), np.ones(4), int(0.5 * NS)) == 'accepted'
    states, info = fc.build(5)
    assert info['first_step'] == 0 and states.shape[0] == 11
    assert np.array_equal(states[3], truth[15])
    assert fc.progress == 50


def test_every_counter_is_the_number_of_times_its_outcome_was_returned():
    """Each message lands in exactly one counter, starting from zero (mutation survivors: a
    counter starting at -1 went unnoticed)."""
    from collections import Counter

    fc = FrameCollector('flock2d', 3, DT)
    assert set(fc.counters.values()) == {0}
    now = 50 * int(DT * NS)
    stamp = lambda s: int(round(s * DT * NS))  # noqa: E731
    messages = [
        (0, stamp(50), np.zeros(4)),
        (1, stamp(50), np.ones(4)),
        (0, stamp(50), np.ones(4)),
        (2, stamp(49), np.zeros(4)),
        (7, stamp(50), np.zeros(4)),
        (1, stamp(50), np.zeros(3)),
        (2, stamp(50), np.array([0, np.nan, 0, 0])),
        (2, -NS, np.zeros(4)),
        (2, now + 10 * NS, np.zeros(4)),
        (2, stamp(50) + int(DT * NS) // 2, np.zeros(4)),
    ]
    returned = Counter(fc.receive(r, t, z, now) for r, t, z in messages)
    assert returned == Counter(
        {
            'accepted': 3,
            'duplicate': 1,
            'unknown_id': 1,
            'bad_size': 1,
            'non_finite': 1,
            'too_old': 1,
            'too_future': 1,
            'off_grid': 1,
        }
    )
    assert fc.counters == {k: returned.get(k, 0) for k in fc.counters}


@pytest.mark.parametrize('steps, every', [([7], 1), ([0, 5, 10], 5), ([3, 7], 4), ([2, 4, 9], 1)])
def test_the_grid_spacing_is_the_gcd_of_the_step_gaps_and_1_for_a_single_step(steps, every):
    fc = FrameCollector('flock2d', 1, DT)
    for s in steps:
        assert fc.add(0, s, np.zeros(4)) == 'accepted'
    states, info = fc.build()
    assert fc.infer_every() == every and info['frame_every'] == every
    assert states.shape[0] == (steps[-1] - steps[0]) // every + 1
