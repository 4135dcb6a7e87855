"""The live monitor without a running swarm: its logic (snapshot, health, links, metrics,
messages, throttle), its RViz markers against known states, its web page served and its
launcher options. The page in a browser and the monitor in a swarm: tests/test_ros_monitor.py."""

import asyncio
import json

import numpy as np
import pytest

from knode_swarm_ros.core.metrics import amd, avd
from knode_swarm_ros.core.network import neighbour_index
from knode_swarm_ros.core.scenarios import get_scenario
from knode_swarm_ros.logic.common import ConfigError
from knode_swarm_ros.logic.monitor import (
    NETWORK_DEFAULTS,
    SwarmWatch,
    Throttle,
    decode_tick,
    hello_message,
    pixel_of,
    tick_message,
    view_scale,
)

DT_NS = 10_000_000  # flock2d: dt 0.01 s


def _states(n=6, seed=0):
    rng = np.random.default_rng(seed)
    return np.concatenate([rng.uniform(-3, 3, (n, 2)), rng.normal(size=(n, 2))], axis=1)


def _watch(states, **kw):
    watch = SwarmWatch('flock2d', range(len(states)), d_cr=kw.pop('d_cr', 2.5), k=kw.pop('k', 3), **kw)
    for i, z in enumerate(states):
        watch.receive(i, 7 * DT_NS, z, wall=100.0)
    return watch


def test_network_defaults_are_the_policies():
    from knode_swarm_ros.core.policy import DEFAULTS

    for scenario, (d_cr, k) in NETWORK_DEFAULTS.items():
        assert (DEFAULTS[scenario]['d_cr'], DEFAULTS[scenario]['k']) == (d_cr, k)


def test_snapshot_links_are_the_cores_neighbour_rule_and_metrics_the_cores():
    states = _states(8)
    snap = _watch(states).snapshot(wall=100.1)
    index, valid = neighbour_index(states, 2, 2.5, 3)
    expected = sorted((i, int(j)) for i in range(8) for j, ok in zip(index[i], valid[i]) if ok)
    assert sorted(map(tuple, snap.links.tolist())) == expected and expected
    assert snap.step == 7 and snap.stamp_ns == 7 * DT_NS and snap.lags.tolist() == [0] * 8
    assert snap.metrics['avd'] == pytest.approx(float(avd(states[:, 2:])))
    assert snap.metrics['amd'] == pytest.approx(float(amd(states[:, :2])))
    gaps = np.linalg.norm(states[:, None, :2] - states[None, :, :2], axis=-1) + np.eye(8) * 1e9
    assert snap.metrics['nnd'] == pytest.approx(gaps.min())
    units = states[:, 2:] / np.linalg.norm(states[:, 2:], axis=1, keepdims=True)
    assert snap.metrics['polarisation'] == pytest.approx(np.linalg.norm(units.mean(0)))
    assert snap.centre == pytest.approx(tuple(states[:, :2].mean(0)))


def test_health_stale_lost_unheard_and_diagnostics():
    states = _states(5)
    watch = SwarmWatch('flock2d', range(6), d_cr=2.5, k=3, stale_after=1.0, lost_after=5.0)
    for i, z in enumerate(states):
        watch.receive(i, 3 * DT_NS, z, wall=100.0)
    watch.receive(0, 4 * DT_NS, states[0], wall=103.0)
    watch.receive(1, 4 * DT_NS, states[1], wall=106.0)
    watch.receive(2, 4 * DT_NS, states[2], wall=106.0)
    watch.diagnostics(1, 1)
    watch.diagnostics(2, 2)
    watch.diagnostics(99, 2)  # not a robot of this swarm: ignored
    assert not watch.receive(2, 1 * DT_NS, states[2], wall=106.0)  # older than the newest: ignored
    snap = watch.snapshot(wall=106.2)
    assert snap.health == ['stale', 'warn', 'error', 'lost', 'lost', 'unheard']
    assert snap.lags.tolist() == [0, 0, 0, 1, 1, 0]
    assert all(5 not in link for link in snap.links.tolist())  # an unheard robot links nobody


def test_receive_many_files_as_one_at_a_time_and_trails_keep_the_newest():
    rng = np.random.default_rng(3)
    robots = [4, 9, 2, 4, 4, 77, 9, 2]  # repeats, and 77: not a robot of this swarm
    stamps = [5, 3, 8, 4, 6, 1, 3, 9]  # robot 4's stamp 4 is older than its 5: ignored
    states = rng.normal(size=(8, 4))
    states[6, 1] = np.nan  # not finite: ignored
    one, many = (SwarmWatch('flock2d', [2, 4, 9], d_cr=2.5, k=3, trail=3, trail_every=0.2) for _ in range(2))
    for walls in ([0.0], [0.1], [0.5, 0.8, 1.1, 1.4]):
        for wall in walls:
            filed_one = [one.receive(r, s * DT_NS, z, wall) for r, s, z in zip(robots, stamps, states)]
            filed_many = many.receive_many(robots, np.array(stamps) * DT_NS, states, wall)
            assert filed_many.tolist() == filed_one == [True, True, True, False, True, False, False, True]
            for a, b in ((one.states, many.states), (one.stamps, many.stamps), (one.arrived, many.arrived)):
                assert np.array_equal(a, b)
            stamps = [s + 10 for s in stamps]
    distinct = SwarmWatch('flock2d', [2, 4, 9], d_cr=2.5, k=3)  # one state per robot: at once
    assert distinct.receive_many([9, 2], [DT_NS, DT_NS], states[:2], 1.0).tolist() == [True, True]
    assert np.array_equal(distinct.states[[2, 0]], states[:2]) and distinct.stamps.tolist() == [
        DT_NS,
        -1,
        DT_NS,
    ]
    unsorted = SwarmWatch('flock2d', [30, -5, 7], d_cr=2.5, k=3)  # ids: any distinct integers, any order
    filed = unsorted.receive_many([7, 99, 30, -5, -6], [DT_NS] * 5, states[:5], 1.0)
    assert filed.tolist() == [True, False, True, True, False]
    assert np.array_equal(unsorted.states, states[[2, 3, 0]])
    # trails: a point per robot every 0.2 s at most (the first state filed then), the last 3
    assert all(np.array_equal(a, b) for a, b in zip(one.trails(), many.trails()))
    trail = many.trails()
    assert [len(t) for t in trail] == [3, 3, 3]
    assert np.array_equal(trail[1], np.repeat(states[:1, :2], 3, axis=0))  # robot 4's first each time
    fresh = SwarmWatch('flock2d', [0], d_cr=2.5, k=3, trail=3, trail_every=0.2)
    for t, wall in enumerate((0.0, 0.1, 0.25, 0.5, 0.75, 1.0)):
        fresh.receive(0, t, np.array([t, -t, 0.0, 0.0]), wall)
    assert fresh.trails()[0].tolist() == [[3, -3], [4, -4], [5, -5]]  # 0.1 s after 0.0: no point


def test_a_tick_without_figures_carries_no_links_nor_metrics():
    states = _states(6)
    watch = _watch(states)
    snap = watch.snapshot(wall=100.0, figures=False)
    assert snap.links is None and snap.metrics is None
    tick = decode_tick(tick_message(snap), 2)
    assert tick['links'] is None and tick['metrics'] is None
    np.testing.assert_allclose(tick['positions'], states[:, :2], atol=5e-4)
    full = watch.snapshot(wall=100.0)
    assert np.array_equal(snap.positions, full.positions) and snap.health == full.health
    watch.diagnostics(0, 3)  # STALE from an agent: error
    watch.diagnostics(1, 0)
    assert watch.snapshot(wall=100.0, figures=False).health[:2] == ['error', 'ok']


def test_messages_round_trip_and_the_pixel_mapping():
    states = _states(6)
    snap = _watch(states).snapshot(wall=100.0)
    tick = decode_tick(tick_message(snap), 2)
    np.testing.assert_allclose(tick['positions'], states[:, :2], atol=5e-4)
    np.testing.assert_allclose(tick['directions'], states[:, 2:], atol=5e-4)
    assert tick['links'].tolist() == snap.links.tolist() and tick['health'] == ['ok'] * 6
    assert tick['step'] == 7 and tick['lags'].tolist() == [0] * 6
    assert tick['metrics']['amd'] == pytest.approx(snap.metrics['amd'], abs=1e-4)
    scale = view_scale(states[:, :2], 960, 720, 2.5)
    hello = json.loads(hello_message('flock2d', range(6), 2.5, 3, scale, (960, 720)))
    assert hello['scale'] == scale and hello['position_dim'] == 2 and hello['health']['s'] == 'stale'
    assert pixel_of(*snap.centre, snap.centre, scale, 960, 720) == (480.0, 360.0)
    col, row = pixel_of(snap.centre[0] + 1.0, snap.centre[1] + 1.0, snap.centre, scale, 960, 720)
    assert (col, row) == pytest.approx((480 + scale, 360 - scale))  # y up on the page


def test_throttle_keeps_to_its_rate():
    throttle = Throttle(10.0)
    due = [t for t in np.arange(0.0, 1.0, 0.01) if throttle.due(t)]
    assert len(due) == 10
    assert not any(Throttle(0.0).due(t) for t in range(3))


def test_markers_of_known_states():
    from visualization_msgs.msg import Marker

    from knode_swarm_ros.nodes.common.markers import HEALTH_RGBA, swarm_markers

    states = np.array([[0.0, 0.0, 1.0, 0.0], [1.0, 0.0, 0.0, 1.0], [5.0, 5.0, 0.0, 0.0]])
    trails = [np.array([[-1.0, 0.0], [0.0, 0.0]]), np.zeros((0, 2)), np.array([[5.0, 4.0]])]
    out = swarm_markers(
        states,
        get_scenario('flock2d'),
        2.0,
        5,
        links=np.array([[0, 1], [1, 0]]),
        health=['ok', 'stale', 'lost'],
        trails=trails,
    )
    by_ns = {}
    for m in out.markers:
        by_ns.setdefault(m.ns, []).append(m)
    robots = by_ns['robots'][0]
    assert [(p.x, p.y) for p in robots.points] == [(0, 0), (1, 0), (5, 5)]
    assert [(c.r, c.g, c.b, c.a) for c in robots.colors] == [
        pytest.approx(HEALTH_RGBA[h]) for h in ('ok', 'stale', 'lost')
    ]
    links = by_ns['links'][0]
    assert links.type == Marker.LINE_LIST
    assert [(p.x, p.y) for p in links.points] == [(0, 0), (1, 0), (1, 0), (0, 0)]
    assert [len(m.points) for m in by_ns['trails']] == [2, 0, 1]
    assert [(p.x, p.y) for p in by_ns['trails'][0].points] == [(-1, 0), (0, 0)]
    heading = by_ns['headings'][1]
    assert [(p.x, p.y) for p in heading.points] == [(1, 0), (1, 0.25)]  # flock2d: velocity x 0.25 s


def test_the_web_server_serves_the_page_and_the_newest_tick():
    import aiohttp

    from knode_swarm_ros.nodes.monitor.web import WebServer, is_loopback

    assert is_loopback('127.0.0.1') and is_loopback('localhost') and is_loopback('::1')
    assert not is_loopback('0.0.0.0') and not is_loopback('192.168.1.4')
    server = WebServer('127.0.0.1', 0)
    server.start()
    try:
        server.publish('{"type":"hello"}', '{"type":"tick","step":1}')

        async def fetch():
            async with aiohttp.ClientSession() as session:
                async with session.get(f'http://127.0.0.1:{server.port}/') as response:
                    page = await response.text()
                async with session.ws_connect(f'ws://127.0.0.1:{server.port}/ws') as ws:
                    hello = (await ws.receive(timeout=60)).data
                    first = (await ws.receive(timeout=60)).data
                    server.publish('{"type":"hello"}', '{"type":"tick","step":2}')
                    second = (await ws.receive(timeout=60)).data
            return page, hello, first, second

        page, hello, first, second = asyncio.run(fetch())
    finally:
        server.stop()
    assert 'window.monitor' in page and 'http://' not in page.replace('http://localhost', '')
    assert (hello, json.loads(first)['step'], json.loads(second)['step']) == ('{"type":"hello"}', 1, 2)


def test_the_web_server_closes_open_pages_when_it_stops():
    import aiohttp

    from knode_swarm_ros.nodes.monitor.web import WebServer

    server = WebServer('127.0.0.1', 0)
    server.start()
    server.publish('{"type":"hello"}', '{"type":"tick","step":1}')

    async def watch():
        async with aiohttp.ClientSession() as session:
            async with session.ws_connect(f'ws://127.0.0.1:{server.port}/ws') as ws:
                await ws.receive(timeout=60)  # hello
                await ws.receive(timeout=60)  # the tick
                await asyncio.get_running_loop().run_in_executor(None, server.stop)
                closing = await ws.receive(timeout=60)
                return closing.type, closing.data  # the frame's code (the reply may meet a closed socket)

    # the page is told the server is going away (its clean-up does not wait for the page to leave)
    assert asyncio.run(watch()) == (aiohttp.WSMsgType.CLOSE, aiohttp.WSCloseCode.GOING_AWAY)


def _plan(tmp_path, *extra):
    from knode_swarm_ros.nodes import swarm

    argv = ['--ground-truth', '--record', str(tmp_path / 'r.npz'), '--log-dir', str(tmp_path / 'logs')]
    return swarm.plan_run(swarm.build_parser().parse_args(argv + ['--domain-id', '40', *extra]))


def test_launcher_monitor_options(tmp_path):
    from knode_swarm_ros.nodes.swarm import build_commands

    plan = _plan(tmp_path)
    assert plan.monitor_port is None and 'monitor' not in build_commands(plan)[0]
    plan = _plan(tmp_path, '--monitor')
    assert (plan.monitor_port, plan.monitor_host) == (8765, '127.0.0.1')
    commands, files = build_commands(plan)
    assert commands['monitor'][2] == 'knode_swarm_ros.nodes.monitor'
    params = files[plan.run_dir / 'monitor.yaml']
    assert params['port'] == 8765 and params['host'] == '127.0.0.1' and params['robots'] == plan.robots
    plan = _plan(tmp_path, '--monitor', '9000', '--monitor-host', '0.0.0.0')
    assert (plan.monitor_port, plan.monitor_host) == (9000, '0.0.0.0')
    with pytest.raises(ConfigError, match='--monitor-host needs --monitor'):
        _plan(tmp_path, '--monitor-host', '0.0.0.0')
    with pytest.raises(ConfigError, match='--monitor PORT'):
        _plan(tmp_path, '--monitor', '70000')
