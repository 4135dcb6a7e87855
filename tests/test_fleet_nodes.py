"""The fleet file's node wiring without a ROS graph (docs/ros.md, "Your own fleet"): PoseStamped
bytes, states from poses equal to the offline rollout's pose observer, velocity setpoints from
the agent logic's commands, a fleet robot that never publishes, swarm --fleet's plan."""

from __future__ import annotations

import numpy as np
import pytest
from geometry_msgs.msg import PoseStamped
from rclpy.serialization import serialize_message

from knode_swarm_ros.core.rollout import PoseObserver
from knode_swarm_ros.core.scenarios import get_scenario
from knode_swarm_ros.logic.agent.agent_logic import AgentConfig, AgentLogic
from knode_swarm_ros.logic.agent.setpoint import SetpointOutput
from knode_swarm_ros.logic.common import ConfigError, stamp_ns
from knode_swarm_ros.logic.contract.fleet import parse_fleet
from knode_swarm_ros.logic.contract.pose import PoseStates
from knode_swarm_ros.nodes.common.conversions import CdrError, pose_from_cdr, pose_to_cdr

DT = 0.05


def _pose_msg(ns, x, y, z=0.0, q=(0.0, 0.0, 0.0, 1.0), frame='world'):
    msg = PoseStamped()
    msg.header.stamp.sec, msg.header.stamp.nanosec = ns // 10**9, ns % 10**9
    msg.header.frame_id = frame
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = x, y, z
    o = msg.pose.orientation
    o.x, o.y, o.z, o.w = q
    return msg


# --- PoseStamped bytes -------------------------------------------------------------------------
@pytest.mark.parametrize('frame', ['', 'w', 'world', 'mocap_frame'])
def test_pose_bytes_decode_as_rclpy_serializes_them_and_encode_to_what_it_reads(frame):
    q = (0.0, 0.0, 0.3826834323650898, 0.9238795325112867)
    data = serialize_message(_pose_msg(12_345_678_901, 1.5, -2.25, 0.5, q, frame))
    assert pose_from_cdr(data) == (12_345_678_901, frame, (1.5, -2.25, 0.5, *q))
    ours = pose_to_cdr(12_345_678_901, (1.5, -2.25, 0.5), q, frame)
    assert len(ours) == len(data) and pose_from_cdr(ours) == pose_from_cdr(data)


def test_big_endian_pose_bytes_decode_too():
    import struct

    body = struct.pack('>iII', 2, 5, 6) + b'world\x00' + bytes(6) + struct.pack('>7d', 1, 2, 3, 0, 0, 0, 1)
    assert pose_from_cdr(b'\x00\x00\x00\x00' + body) == (2_000_000_005, 'world', (1, 2, 3, 0, 0, 0, 1))


@pytest.mark.parametrize(
    'mutate',
    [
        lambda b: b[:-1],  # truncated
        lambda b: b + b'\x00' * 8,  # trailing bytes: not a PoseStamped
        lambda b: b'\x00\x05' + b[2:],  # unknown encapsulation
        lambda b: b[:12] + b'\xff\xff\x00\x00' + b[16:],  # frame_id longer than the message
        lambda b: b'',
    ],
)
def test_malformed_pose_bytes_raise_cdr_error(mutate):
    data = serialize_message(_pose_msg(10**9, 1.0, 2.0))
    with pytest.raises(CdrError):
        pose_from_cdr(mutate(data))


# --- states from poses ---------------------------------------------------------------------------
def test_states_from_poses_robot_by_robot_equal_the_offline_pose_observer_bit_for_bit():
    spec = get_scenario('flock2d')
    rng = np.random.default_rng(4)
    z = np.cumsum(rng.normal(0, 0.1, (30, 5, 4)), axis=0)
    observer, poses = PoseObserver(spec, 7), PoseStates(spec, 7)
    for t in range(30):
        ns = stamp_ns(t, DT)
        heard = observer.observe(ns, z[t])
        for r in (3, 0, 4, 1, 2):  # any arrival order within a step
            mine = poses.state(r, ns, (*z[t, r, :2], 0.0), (0.0, 0.0, 0.0, 1.0))
            assert np.array_equal(mine, heard[r])
    assert np.array_equal(poses.velocity(2), heard[2, 2:])


def test_a_non_finite_pose_is_mapped_but_not_fed_to_the_estimator():
    poses = PoseStates('flock2d', 3)
    poses.state(0, stamp_ns(0, DT), (0.0, 0.0, 0.0), (0, 0, 0, 1))
    assert np.isnan(poses.state(0, stamp_ns(1, DT), (np.nan, 0.0, 0.0), (0, 0, 0, 1))[0])
    z = poses.state(0, stamp_ns(2, DT), (0.2, 0.0, 0.0), (0, 0, 0, 1))
    assert z[2] == pytest.approx(2.0) and np.all(np.isfinite(z))  # the NaN sample is not in the fit


@pytest.mark.parametrize('offset_ns', [0, 3_000_000])
def test_poses_faster_than_the_policy_file_the_newest_at_or_before_each_step(offset_ns):
    # 100 Hz poses under a 20 Hz policy, on the grid and 3 ms off it: each step gets the newest
    # pose at or before its time, with the estimate every pose before it gives (bit for bit)
    rng = np.random.default_rng(6)
    every, filed = PoseStates('flock2d', 10), PoseStates('flock2d', 10, DT)
    heard, got = [], {}
    for j in range(60):
        ns = offset_ns + j * 10_000_000
        pose = ((*rng.normal(size=2), 0.0), (0.0, 0.0, 0.0, 1.0))
        heard.append((ns, every.state(1, ns, *pose)))
        for step, stamp, mine, _own in filed.filed(1, ns, *pose):
            got[step] = (stamp, mine)
    assert sorted(got) == list(range(1 if offset_ns else 0, 12))
    for step, (stamp, mine) in got.items():
        want_ns, want = [(ns, z) for ns, z in heard if ns <= stamp_ns(step, DT)][-1]
        assert stamp == want_ns and np.array_equal(mine, want)


def test_a_repeated_pose_files_its_state_again_and_a_non_finite_one_is_handed_back_unfiled():
    poses = PoseStates('flock2d', 3, DT)
    first = poses.filed(0, 0, (0.0, 0.0, 0.0), (0, 0, 0, 1))
    assert [(s, ns, own) for s, ns, _, own in first] == [(0, 0, None)]
    again = poses.filed(0, 0, (0.0, 0.0, 0.0), (0, 0, 0, 1))  # the simulator re-publishes step 0
    assert again[0][0] == 0 and np.array_equal(again[0][2], first[0][2])
    ((step, ns, z, _own),) = poses.filed(0, 10_000_000, (np.nan, 0.0, 0.0), (0, 0, 0, 1))
    assert step is None and np.isnan(z[0])
    assert poses.filed(0, 20_000_000, (0.02, 0.0, 0.0), (0, 0, 0, 1)) == []


def test_a_state_without_velocity_is_the_pose_itself():
    poses = PoseStates('boids3d')
    z = poses.state(0, 0, (1.0, 2.0, 3.0), (0.0, 0.0, 0.0, 1.0))
    assert np.array_equal(z, [1.0, 2.0, 3.0, 1.0, 0.0, 0.0]) and not poses.estimates


# --- velocity setpoints through the agent logic -------------------------------------------------
class ConstantPolicy:
    """A numpy stand-in for a policy file returning one acceleration."""

    def __init__(self, u, limit=None):
        self.scenario, self.k, self.d_cr, self.tau, self.dt = 'flock2d', 4, 5.0, 0, DT
        self.command_limit = limit
        self.u = np.asarray(u, dtype=np.float64)

    def __call__(self, Y, mask):
        return np.tile(self.u, (Y.shape[0], 1))


@pytest.mark.parametrize(
    'u, v, limit, speed_limit, want',
    [
        ((1.0, 2.0), (0.5, -0.2), None, None, (0.55, -0.1)),  # v + u T, T = 0.05
        ((1.0, 2.0), (0.5, -0.2), None, 0.52, (0.52, -0.1)),  # clipped per axis at speed_limit
        ((-4.0, 0.0), (-0.9, 0.3), None, 1.0, (-1.0, 0.3)),
        ((10.0, -10.0), (0.0, 0.0), 2.0, None, (0.1, -0.1)),  # the policy's command_limit first
    ],
)
def test_an_acceleration_command_becomes_v_plus_u_t(u, v, limit, speed_limit, want):
    logic = AgentLogic(AgentConfig(0, [0, 1], mode='lockstep'), ConstantPolicy(u, limit))
    own = np.array([0.0, 0.0, *v])
    logic.receive(1, 0, np.array([1.0, 0.0, 0.0, 0.0]), wall=0.0)
    logic.receive(0, 0, own, wall=0.0)
    cmd = logic.lockstep_poll(0.0)
    value = SetpointOutput(DT, speed_limit).value(cmd, own[2:])
    assert value == pytest.approx(want, abs=1e-15)


def test_a_stop_command_is_a_zero_setpoint():
    logic = AgentLogic(AgentConfig(0, [0], mode='realtime', control_rate=20.0), ConstantPolicy((1.0, 1.0)))
    logic.receive(0, 0, np.array([0.0, 0.0, 0.4, 0.4]), 0, wall=0.0)
    cmd = logic.tick(10**9)  # the own state is a second old: stop
    assert cmd.stop and np.array_equal(SetpointOutput(DT, 1.0).value(cmd, np.array([0.4, 0.4])), [0.0, 0.0])


# --- a fleet robot that never publishes ----------------------------------------------------------
class RowsPolicy(ConstantPolicy):
    def __init__(self):
        super().__init__((0.0, 0.0))
        self.masks = []

    def __call__(self, Y, mask):
        self.masks.append(np.array(mask))
        return super().__call__(Y, mask)


def test_a_fleet_robot_that_never_publishes_is_left_out_of_y_named_and_may_join_late():
    fleet = parse_fleet({'robots': {'cf231': {'id': 0}, 'cf5': {'id': 7}, 'cf9': {'id': 9}}})
    policy = RowsPolicy()
    logic = AgentLogic(AgentConfig(0, fleet.ids, mode='realtime', control_rate=20.0), policy)
    for s in range(1, 4):  # cf9 never publishes (the clock runs: silent robots can be judged)
        ns = stamp_ns(s, DT)
        logic.receive(7, ns, np.array([1.0, 0.0, 0.0, 0.0]), ns, wall=s)
        logic.receive(0, ns, np.array([0.0, 0.0, 0.0, 0.0]), ns, wall=s)
        cmd = logic.realtime_poll(ns, wall=s)
        assert cmd is not None and cmd.neighbours == 1 and policy.masks[-1].sum() == 2
    assert [fleet.name_of(i) for i in logic.status()['missing']] == ['cf9']
    ns = stamp_ns(4, DT)  # cf9 joins late
    logic.receive(9, ns, np.array([0.0, 1.0, 0.0, 0.0]), ns, wall=4)
    logic.receive(7, ns, np.array([1.0, 0.0, 0.0, 0.0]), ns, wall=4)
    logic.receive(0, ns, np.array([0.0, 0.0, 0.0, 0.0]), ns, wall=4)
    assert logic.realtime_poll(ns, wall=4).neighbours == 2 and logic.status()['missing'] == []


def test_the_agent_names_the_robots_it_never_heard():
    from knode_swarm_ros.nodes.agent.plumbing import missing_names

    fleet = parse_fleet(
        {
            'robots': {'cf231': {'id': 0}, 'cf5': {'id': 7}},
            'state': {'topic': '/vrpn_mocap/{name}/pose', 'type': 'pose'},
        }
    )
    assert missing_names(fleet, [7]) == 'cf5 (id 7) on /vrpn_mocap/cf5/pose'


def test_own_id_from_name_or_id():
    from knode_swarm_ros.nodes.agent.node import own_id

    fleet = parse_fleet({'robots': {'cf231': {'id': 0}, 'cf5': {'id': 7}}})
    assert own_id(fleet, -1, 'cf5', True) == 7 and own_id(fleet, 7, 'cf5', True) == 7
    assert own_id(fleet, 3, '', False) == 3
    with pytest.raises(ConfigError, match="'name' = 'cf5' is robot 7"):
        own_id(fleet, 0, 'cf5', True)
    with pytest.raises(ConfigError, match='cf6.*not in the fleet'):
        own_id(fleet, -1, 'cf6', True)
    with pytest.raises(ConfigError, match='name:=NAME'):
        own_id(fleet, -1, '', True)


# --- swarm --fleet ---------------------------------------------------------------------------------
def _args(tmp_path, *extra):
    from knode_swarm_ros.nodes.swarm.cli import build_parser

    return build_parser().parse_args(
        ['--record', str(tmp_path / 'r.npz'), '--domain-id', '7', *map(str, extra)]
    )


def test_swarm_fleet_passes_the_fleet_to_every_node_and_runs_its_ids(tmp_path):
    from knode_swarm_ros.nodes.swarm.commands import build_commands
    from knode_swarm_ros.nodes.swarm.plan import plan_run

    fleet = tmp_path / 'fleet.yaml'
    fleet.write_text('robots: {a: {id: 4}, b: {id: 9}}\nstate: {topic: "/m/{name}/pose", type: pose}\n')
    plan = plan_run(
        _args(tmp_path, '--fleet', fleet, '--pose-noise', 0.002, '--mode', 'realtime', '--pose-rate', 10)
    )
    assert plan.robots == 2 and plan.fleet_ids == [4, 9]
    commands, files = build_commands(plan)
    assert {'agent_4', 'agent_9'} <= set(commands)
    params = {path.name: p for path, p in files.items()}
    assert params['simulator.yaml']['fleet'] == str(fleet) and params['simulator.yaml']['pose_noise'] == 0.002
    assert params['simulator.yaml']['publish_rate'] == 10.0
    assert params['recorder.yaml']['fleet'] == str(fleet) and params['agent.yaml']['fleet'] == str(fleet)


def test_a_motion_capture_faster_than_the_policy_is_simulated_in_sub_steps(tmp_path):
    from knode_swarm_ros.nodes.simulator.node import substeps_of
    from knode_swarm_ros.nodes.swarm.commands import build_commands
    from knode_swarm_ros.nodes.swarm.plan import plan_run

    fleet = tmp_path / 'fleet.yaml'
    fleet.write_text(
        'robots: {a: {id: 4}, b: {id: 9}}\nstate: {topic: "/m/{name}/pose", type: pose, rate: 100}\n'
    )
    for extra in (('--pose-rate', 100), ()):  # the fleet's stated rate is the default
        plan = plan_run(_args(tmp_path, '--fleet', fleet, '--mode', 'realtime', *extra))
        sim = {path.name: p for path, p in build_commands(plan)[1].items()}['simulator.yaml']
        assert sim['state_rate'] == 100.0 and plan.pose_rate == 100.0
        assert substeps_of(sim['state_rate'], plan.dt, 'realtime') == int(round(100 * plan.dt))
    assert substeps_of(0.0, 0.05, 'realtime') == 1 and substeps_of(100.0, 0.05, 'realtime') == 5
    for rate, mode in ((90.0, 'realtime'), (100.0, 'lockstep')):
        with pytest.raises(ConfigError, match='state_rate'):
            substeps_of(rate, 0.05, mode)


@pytest.mark.parametrize(
    'extra, match',
    [
        (('--pose-noise', 0.01), 'need --fleet'),
        (('--fleet', 'ODOM', '--pose-noise', 0.01), 'gives odometry, not poses'),
        (('--fleet', 'POSE', '--pose-rate', 105, '--mode', 'realtime'), 'at most 1 / dt'),
        (('--fleet', 'POSE', '--pose-rate', 100), 'realtime only'),
        (('--fleet', 'RATED', '--pose-rate', 50, '--mode', 'realtime'), 'states rate 100 Hz'),
        (('--fleet', 'POSE', '--robots', 3), 'has 2 robots'),
    ],
)
def test_swarm_fleet_flags_are_checked(tmp_path, extra, match):
    from knode_swarm_ros.nodes.swarm.plan import plan_run

    (tmp_path / 'odom.yaml').write_text('robots: {a: {id: 4}, b: {id: 9}}\n')
    (tmp_path / 'pose.yaml').write_text('robots: {a: {id: 4}, b: {id: 9}}\nstate: {type: pose}\n')
    (tmp_path / 'rated.yaml').write_text('robots: {a: {id: 4}, b: {id: 9}}\nstate: {type: pose, rate: 100}\n')
    extra = [str(tmp_path / f'{e.lower()}.yaml') if e in ('ODOM', 'POSE', 'RATED') else e for e in extra]
    with pytest.raises(ConfigError, match=match):
        plan_run(_args(tmp_path, *extra))


def test_the_launcher_names_the_fleet_robots_no_agent_has_heard(tmp_path, capsys):
    import types

    from knode_swarm_ros.logic.reporting import write_json_report
    from knode_swarm_ros.logic.simulator.run_phases import LifecycleConfig, SimLifecycle
    from knode_swarm_ros.logic.simulator.swarm_sim import SwarmSim, initial_state
    from knode_swarm_ros.nodes.swarm.report import name_never_heard

    z0, _ = initial_state('flock2d', 3, 0)
    sim = SwarmSim('flock2d', z0, DT, 'realtime')
    logs, now = [], [0.0]
    out = types.SimpleNamespace(
        publish_frame=lambda: None,
        publish_status=lambda: None,
        log=lambda level, text: logs.append((level, text)),
        start_physics=lambda period: None,
        stop_physics=lambda: None,
        finish=lambda code: None,
    )
    life = SimLifecycle(
        sim, LifecycleConfig(steps=5, mode='realtime', startup_timeout=10.0), out, {}, lambda: now[0]
    )
    for r in range(
        3
    ):  # cf9 (robot 2) never publishes: every agent says so; robot 0's agent also lacks cf5 for now
        life.on_agent_status(r, {'ready': False, 'missing_names': ['cf9'] + (['cf5'] if r == 0 else [])})
    life.on_agent_status(0, {'ready': False, 'missing_names': ['cf9']})  # the newest status counts
    now[0] = 11.0
    life.on_watchdog(now[0])
    assert logs[-1][0] == 'error' and logs[-1][1].endswith('never heard by the agents: cf9')
    run_dir = tmp_path / 'run'
    run_dir.mkdir()
    write_json_report(str(run_dir / 'simulator.json'), life.report())
    assert name_never_heard(types.SimpleNamespace(run_dir=run_dir)) == ['cf9']
    assert 'never heard by the agents: cf9' in capsys.readouterr().out
    (run_dir / 'simulator.json').unlink()
    assert name_never_heard(types.SimpleNamespace(run_dir=run_dir)) == []


def test_the_launcher_gives_the_fleet_to_the_monitor_and_the_lifecycle_manager(tmp_path):
    from knode_swarm_ros.nodes.swarm.cli import build_parser
    from knode_swarm_ros.nodes.swarm.commands import build_commands
    from knode_swarm_ros.nodes.swarm.plan import plan_run

    fleet = tmp_path / 'fleet.yaml'
    fleet.write_text('robots: {a: {id: 4}, b: {id: 9}}\n')
    fleet = str(fleet)
    args = [
        '--record',
        str(tmp_path / 'r.npz'),
        '--domain-id',
        '7',
        '--fleet',
        fleet,
        '--managed',
        '--monitor',
        '0',
    ]
    commands, files = build_commands(plan_run(build_parser().parse_args(args)))
    params = {path.name: p for path, p in files.items()}
    assert params['monitor.yaml']['fleet'] == fleet
    assert f'fleet:={fleet}' in ' '.join(commands['lifecycle_manager'])
    assert {'agent_4', 'agent_9'} <= set(commands)
