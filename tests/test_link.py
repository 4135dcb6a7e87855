"""The link model (knode_swarm_ros/core/link.py): loss, delay, jitter, radio range.

Statistics are checked against their known distributions with intervals wide enough for a
fixed seed to sit well inside (a binomial count within 4.5 standard deviations of its mean),
delays against their configured support exactly, and the model switched off against the
canonical rollout bit for bit.
"""

import math

import numpy as np
import pytest

from knode_swarm_ros.core import rollout
from knode_swarm_ros.core.link import LinkConfig, LinkModel, link_rollout


def _binomial_ok(count, trials, p, z=4.5):
    mean, sd = trials * p, math.sqrt(trials * p * (1 - p))
    return abs(count - mean) <= z * sd


def _local_tanner(Y, mask):
    """A numpy policy: the Tanner law over the rows of Y (fast, deterministic, no torch)."""
    rel = Y[:, 1:, :2] - Y[:, :1, :2]
    r2 = np.maximum(np.sum(rel * rel, axis=-1), 1e-6)
    c = (1 / r2 - 1 / r2**2) * mask[:, 1:]
    u = 2 * np.einsum('bj,bjd->bd', c, rel) + np.einsum(
        'bj,bjd->bd', mask[:, 1:] * 1.0, Y[:, 1:, 2:] - Y[:, :1, 2:]
    )
    return np.clip(u, -10, 10)


def _swarm(S=2, n=6, seed=0):
    rng = np.random.default_rng(seed)
    return np.concatenate([rng.uniform(-2, 2, (S, n, 2)), rng.normal(size=(S, n, 2))], axis=-1)


def test_settings_are_checked_and_off_by_default():
    assert not LinkConfig().enabled and LinkConfig(range=3.0).enabled
    for bad, name in (
        (LinkConfig(loss=1.0), 'link_loss'),
        (LinkConfig(loss=-0.1), 'link_loss'),
        (LinkConfig(delay=-1.0), 'link_delay'),
        (LinkConfig(jitter=math.nan), 'link_jitter'),
        (LinkConfig(range=-2.0), 'link_range'),
        (LinkConfig(seed=-1), 'link_seed'),
    ):
        with pytest.raises(ValueError, match=name):
            bad.validate()


def test_drop_rate_is_within_its_binomial_interval_and_seeded():
    for loss in (0.05, 0.2, 0.5):
        model = LinkModel(LinkConfig(loss=loss, seed=7))
        fates = [model.fate()[0] for _ in range(20_000)]
        lost = fates.count('lost')
        assert model.counters == {
            'offered': 20_000,
            'out_of_range': 0,
            'lost': lost,
            'delivered': 20_000 - lost,
        }
        assert _binomial_ok(lost, 20_000, loss), (loss, lost)
        again = LinkModel(LinkConfig(loss=loss, seed=7))
        assert [again.fate()[0] for _ in range(20_000)] == fates  # same seed, same draws
    a, b = LinkModel(LinkConfig(loss=0.3, seed=8)), LinkModel(LinkConfig(loss=0.3, seed=9))
    assert [a.fate()[0] for _ in range(50)] != [b.fate()[0] for _ in range(50)]


def test_delays_are_as_configured_and_the_queue_delivers_in_arrival_order():
    fixed = LinkModel(LinkConfig(delay=0.25))
    for k in range(100):
        assert fixed.offer(k * 0.01, k) == 'delivered'
    assert set(fixed.delays) == {0.25}
    assert fixed.due(0.2499) == [] and fixed.due(0.25) == [0] and fixed.due(0.26) == [1]
    assert fixed.pending == 98 and fixed.due(10.0) == list(range(2, 100))
    jit = LinkModel(LinkConfig(delay=0.1, jitter=0.2, seed=3))
    for k in range(20_000):
        jit.offer(0.0, k)
    d = np.array(jit.delays)
    assert d.min() >= 0.1 and d.max() <= 0.3
    # U[0.1, 0.3]: mean 0.2 within 4.5 standard errors; a quarter of the mass in each quarter
    assert abs(d.mean() - 0.2) <= 4.5 * (0.2 / math.sqrt(12)) / math.sqrt(d.size)
    counts = np.histogram(d, bins=4, range=(0.1, 0.3))[0]
    assert all(_binomial_ok(c, d.size, 0.25) for c in counts)
    out = jit.due(0.3)
    assert len(out) == 20_000 and out != list(range(20_000))  # jitter reorders messages


def test_radio_range_silences_distant_robots_only():
    model = LinkModel(LinkConfig(range=2.0))
    assert model.fate([0.0, 0.0], [2.0, 0.0])[0] == 'delivered'  # inclusive, like d_cr
    assert model.fate([0.0, 0.0], [1.5, 1.5])[0] == 'out_of_range'
    assert model.fate([0.0, 0.0, 0.0], [0.0, 0.0, 1.9])[0] == 'delivered'
    assert model.counters['out_of_range'] == 1 and model.counters['offered'] == 3


def test_link_rollout_switched_off_is_the_canonical_rollout_bit_for_bit():
    z0 = _swarm()
    for tau in (0, 3):
        ref = rollout(_local_tanner, z0, 60, 'flock2d', 2.5, 4, tau, 0.01)
        got, stats = link_rollout(_local_tanner, z0, 60, 'flock2d', 2.5, 4, tau, 0.01)
        assert np.array_equal(got, ref)
        assert stats['lost'] == stats['out_of_range'] == 0 and stats['delays'] == {0: stats['delivered']}
        assert stats['offered'] == 2 * 61 * 6 * 5


def _recording_policy(log):
    def policy(Y, mask):
        log.append((Y.copy(), mask.copy()))
        return np.zeros((Y.shape[0], 2))

    return policy


def test_link_rollout_delays_losses_and_range_are_what_the_robots_see():
    z0 = _swarm(S=1, n=4, seed=2)
    D, n = 3, 4
    log = []
    states, stats = link_rollout(
        _recording_policy(log), z0, 12, 'flock2d', 100.0, n, 0, 0.01, LinkConfig(delay=D)
    )
    assert stats['delays'] == {D: stats['delivered']}
    for t, (Y, mask) in enumerate(log):
        Y, mask = Y.reshape(1, n, n, 4)[0], mask.reshape(1, n, n)[0]
        assert np.array_equal(Y[:, 0], states[0, t])  # own row: now, no link
        if t < D:
            assert not mask[:, 1:].any()  # nothing has arrived yet
        else:
            seen = {tuple(row) for row in Y[:, 1:][mask[:, 1:]]}
            assert seen == {tuple(z) for z in states[0, t - D]}
            assert mask.sum() == n * n  # every peer heard, D steps late
    # Loss: the lost fraction is binomial; range: two groups 50 apart never hear each other.
    z0 = _swarm(S=3, n=8, seed=4)
    z0[:, 4:, 0] += 50.0
    log = []
    _, stats = link_rollout(
        _recording_policy(log),
        z0,
        40,
        'flock2d',
        100.0,
        8,
        0,
        0.01,
        LinkConfig(loss=0.25, range=20.0, seed=5),
    )
    in_range = stats['offered'] - stats['out_of_range']
    assert stats['out_of_range'] == 3 * 41 * 8 * 4  # every cross-group message
    assert _binomial_ok(stats['lost'], in_range, 0.25)
    for Y, mask in log:
        far = np.abs(Y[:, 1:, 0] - Y[:, :1, 0]) > 25
        assert not (far & mask[:, 1:]).any()


def test_link_rollout_forgets_peers_silent_longer_than_the_timeout():
    z0 = _swarm(S=1, n=3, seed=6)
    log = []
    link_rollout(
        _recording_policy(log),
        z0,
        30,
        'flock2d',
        100.0,
        3,
        0,
        0.01,
        LinkConfig(loss=0.999999, seed=1),
        timeout_steps=5,
    )
    assert not any(mask[:, 1:].any() for _, mask in log)  # nothing arrives, nobody is heard
    with pytest.raises(ValueError, match='whole steps'):
        link_rollout(_recording_policy([]), z0, 3, 'flock2d', 1.0, 3, 0, 0.01, LinkConfig(delay=0.5))


def test_a_radio_range_below_one_metre_is_applied():
    """Any positive range counts (mutation survivor: only ranges above 1 were applied); the edge
    itself (distance == range) is in range."""
    model = LinkModel(LinkConfig(range=0.5))
    assert model.fate([0.0, 0.0], [0.3, 0.4])[0] == 'delivered'  # exactly 0.5 apart
    assert model.fate([0.0, 0.0], [0.3, 0.41])[0] == 'out_of_range'
    assert model.fate([0.0, 0.0], None)[0] == 'delivered'  # no positions: no range check
    assert model.counters == {'offered': 3, 'out_of_range': 1, 'lost': 0, 'delivered': 2}


@pytest.mark.parametrize(
    'config, positions, expected',
    [
        (LinkConfig(range=1.0, delay=3.0), ([0.0, 0.0], [2.0, 0.0]), ('out_of_range', 0.0)),
        (LinkConfig(loss=0.999999, delay=3.0, seed=1), (None, None), ('lost', 0.0)),
        (LinkConfig(range=1.0, delay=3.0), ([0.0, 0.0], [1.0, 0.0]), ('delivered', 3.0)),
    ],
)
def test_a_message_not_delivered_has_no_delay(config, positions, expected):
    model = LinkModel(config)
    assert model.fate(*positions) == expected
    assert model.counters[expected[0]] == 1 and model.delays == [expected[1]] * (expected[0] == 'delivered')


@pytest.mark.parametrize(
    'delay, timeout, heard', [(50, None, True), (51, None, False), (5, 5, True), (6, 5, False)]
)
def test_a_peer_is_heard_while_its_newest_state_is_at_most_timeout_steps_old(delay, timeout, heard):
    """Every message arrives exactly ``delay`` steps late: from step ``delay`` on, the peers are
    neighbours iff delay <= timeout_steps (default 50: the agent's 0.5 s state_timeout at dt 0.01)."""
    log = []
    extra = {} if timeout is None else {'timeout_steps': timeout}
    link_rollout(
        _recording_policy(log),
        _swarm(S=1, n=3, seed=6),
        delay + 3,
        'flock2d',
        100.0,
        3,
        0,
        0.01,
        LinkConfig(delay=float(delay)),
        **extra,
    )
    assert [bool(mask[:, 1:].all()) for _, mask in log] == [False] * delay + [heard] * 3
    assert not any(mask[:, 1:].any() for _, mask in log[:delay])


@pytest.mark.parametrize('delay, jitter, tau', [(0, 3, 0), (0, 2, 2), (1, 2, 1), (2, 0, 3)])
def test_link_rollout_hears_the_newest_arrived_state_by_brute_force(delay, jitter, tau):
    """The rollout updates what each robot holds only from the send steps that can have become
    usable at step t; the definition, checked here over every past send step: robot i holds
    robot j's newest state sent at s <= max(t - tau, 0) that has arrived (s + lag <= t)."""
    S, n, steps, seed = 2, 4, 14, 9
    log = []
    states, _ = link_rollout(
        _recording_policy(log),
        _swarm(S=S, n=n, seed=3),
        steps,
        'flock2d',
        100.0,
        n,
        tau,
        0.01,
        LinkConfig(delay=float(delay), jitter=float(jitter), seed=seed),
    )
    rng = np.random.default_rng(seed)  # the rollout's draws: one lag per (swarm, receiver, sender) per step
    arrival = np.stack(
        [
            t + delay + (rng.integers(0, jitter + 1, size=(S, n, n)) if jitter else np.zeros((S, n, n)))
            for t in range(steps + 1)
        ]
    )
    for t, (Y, mask) in enumerate(log):
        Y, mask, newest = Y.reshape(S, n, n, 4), mask.reshape(S, n, n), max(t - tau, 0)
        for a in range(S):
            for i in range(n):
                held = [
                    max((s for s in range(newest + 1) if arrival[s, a, i, j] <= t), default=-1)
                    for j in range(n)
                ]
                want = {tuple(states[a, held[j], j]) for j in range(n) if j != i and held[j] >= 0}
                assert {tuple(row) for row in Y[a, i, 1:][mask[a, i, 1:]]} == want, (t, a, i)


def test_the_delay_statistics_keep_the_first_100000_delays():
    model = LinkModel(LinkConfig(delay=0.25))
    for _ in range(100_001):
        model.fate()
    assert model.counters['delivered'] == 100_001 and len(model.delays) == 100_000
