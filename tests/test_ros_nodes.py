"""The nodes in this process on an isolated ROS domain, and the agent executable's start and errors.

Hand-made Odometry goes in; the agent's command must be what the core computes for the same
Y_i, the recorder's file what was published. Waiting is always a polled condition with a
deadline, never a fixed sleep.
"""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import rclpy
from geometry_msgs.msg import AccelStamped
from nav_msgs.msg import Odometry
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Float64, Int64, String

from knode_swarm_ros.logic.common import ConfigError, parse_status
from knode_swarm_ros.nodes.common import qos
from knode_swarm_ros.nodes.common.conversions import msg_to_command, state_to_odom, time_msg

pytestmark = pytest.mark.ros

REPO = Path(__file__).resolve().parents[1]
SEC = 1_000_000_000


@pytest.fixture
def flock_policy(untrained_policies):
    return untrained_policies['flock2d']


@pytest.fixture
def ros(monkeypatch, ros_domain_id):
    """An rclpy context of its own on a claimed domain, localhost only; shut down afterwards."""
    domain = ros_domain_id
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    monkeypatch.setenv('ROS_DOMAIN_ID', str(domain))
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain)
    nodes = []
    executor = SingleThreadedExecutor(context=context)

    class Ros:
        def add(self, node):
            nodes.append(node)
            executor.add_node(node)
            return node

        def node(self, name):
            return self.add(Node(name, context=context))

        def spin_until(self, condition, timeout=20.0, each=None):
            deadline = time.monotonic() + timeout
            while time.monotonic() < deadline:
                if each is not None:
                    each()
                executor.spin_once(timeout_sec=0.05)
                if condition():
                    return True
            return False

    Ros.context = context
    yield Ros()
    for node in nodes:
        executor.remove_node(node)
        node.destroy_node()
    executor.shutdown()
    rclpy.try_shutdown(context=context)


def _agent(ros, **params):
    from knode_swarm_ros.nodes.agent.node import AgentNode

    overrides = [Parameter(k, value=v) for k, v in params.items()]
    return ros.add(
        AgentNode(f'agent_{params.get("id", 0)}', context=ros.context, parameter_overrides=overrides)
    )


def test_agent_publishes_the_command_the_core_predicts(ros, flock_policy):
    from knode_swarm_ros.core import load_policy, neighbour_matrix_single

    agent = _agent(ros, id=1, robots=4, policy=str(flock_policy), mode='lockstep', use_sim_time=True)
    io = ros.node('test_io')
    pubs = {r: io.create_publisher(Odometry, f'robot_{r}/odom', qos.ODOM) for r in range(4)}
    commands, statuses = [], []
    io.create_subscription(AccelStamped, 'robot_1/cmd_accel', commands.append, qos.COMMAND)
    io.create_subscription(
        String, 'robot_1/agent_status', lambda m: statuses.append(parse_status(m.data)), qos.STATUS
    )
    Z = np.array([[0.0, 0.0, 1.0, 0.0], [0.8, 0.3, 0.0, 1.0], [1.5, -0.4, -0.5, 0.5], [9.0, 9.0, 0.0, 0.0]])
    stamp = 3 * 10_000_000  # step 3 of dt 0.01

    def publish():  # peers first, the own state last; repeated until discovery has happened
        for r in (3, 2, 0, 1):
            pubs[r].publish(state_to_odom(r, stamp, Z[r], 'flock2d'))

    assert ros.spin_until(lambda: commands, each=publish), 'no command from the agent'
    ns, u = msg_to_command(commands[0], 'flock2d')
    assert ns == stamp  # the stamp of the own state it was computed from
    policy = load_policy(flock_policy)
    Y, mask = neighbour_matrix_single(1, Z[1], Z, 2, policy.d_cr, policy.k)
    assert mask.tolist() == [True, True, True, False, False, False]  # robot 3 is beyond d_cr
    expected = np.clip(policy(Y[None], mask[None])[0], -10.0, 10.0)
    assert np.allclose(u, expected, rtol=0, atol=1e-6)
    assert ros.spin_until(lambda: statuses and statuses[-1]['ready'])
    assert statuses[-1]['heard'] == 4 and statuses[-1]['answered'] == 3

    # What a bad network delivers is dropped and counted.
    bad = state_to_odom(2, stamp + 10_000_000, Z[2], 'flock2d')
    bad.pose.pose.position.x = float('nan')
    stranger = state_to_odom(9, stamp + 10_000_000, Z[2], 'flock2d')  # claims robot 9 on robot_2/odom
    pubs[2].publish(bad)
    pubs[2].publish(stranger)
    pubs[2].publish(b'\x00\x01\x00\x00 not an Odometry')  # serialized bytes that do not decode
    counters = agent.logic.counters
    assert ros.spin_until(
        lambda: (counters['non_finite'], counters['unknown_id'], counters['malformed']) == (1, 1, 1)
    )


@pytest.mark.parametrize('tick', ['state', 'timer'])
def test_realtime_agent_ticks_on_sim_time_and_stops_when_its_state_is_stale(ros, flock_policy, tick):
    _agent(
        ros,
        id=0,
        robots=2,
        policy=str(flock_policy),
        mode='realtime',
        use_sim_time=True,
        control_rate=10.0,
        state_timeout=0.3,
        realtime_tick=tick,
    )
    io = ros.node('test_clock')
    clock = io.create_publisher(Clock, '/clock', qos.CLOCK)
    pubs = {r: io.create_publisher(Odometry, f'robot_{r}/odom', qos.ODOM) for r in range(2)}
    commands = []
    io.create_subscription(
        AccelStamped,
        'robot_0/cmd_accel',
        lambda m: commands.append(msg_to_command(m, 'flock2d')),
        qos.COMMAND,
    )
    Z = np.array([[0.0, 0.0, 1.0, 0.0], [0.8, 0.3, 0.0, 1.0]])
    t = [SEC]

    calls = [0]

    def fresh():  # states at t, then the clock at t, advancing 0.1 s every 4th call (spin_once runs one
        calls[0] += (
            1  # callback: publishing 3 messages each time would outrun the agent until its states are too old)
        )
        if calls[0] % 4:
            return
        t[0] += SEC // 10
        for r in range(2):
            pubs[r].publish(state_to_odom(r, t[0], Z[r], 'flock2d'))
        clock.publish(Clock(clock=time_msg(t[0])))

    # The command the core predicts for both robots heard (states never change, so any delay
    # gives the same Y); earlier ticks may see robot 0 alone.
    from knode_swarm_ros.core import load_policy, neighbour_matrix_single

    policy = load_policy(flock_policy)
    Y, mask = neighbour_matrix_single(0, Z[0], Z, 2, policy.d_cr, policy.k)
    assert mask.tolist()[:2] == [True, True]
    expected = np.clip(policy(Y[None], mask[None])[0], -10.0, 10.0)
    assert np.any(expected != 0)

    def predicted(u):
        return np.allclose(u, expected, rtol=0, atol=1e-6)

    assert ros.spin_until(lambda: any(predicted(u) for _, u in commands), each=fresh)
    stamp, u = next(c for c in commands if predicted(c[1]))
    assert stamp % (SEC // 10) == 0 and stamp > SEC
    last_state = t[0]
    commands.clear()

    def clock_only():  # time goes on, no state arrives
        t[0] += SEC // 10
        clock.publish(Clock(clock=time_msg(t[0])))

    assert ros.spin_until(
        lambda: any(ns > last_state + 3 * SEC // 10 and np.all(u == 0) for ns, u in commands), each=clock_only
    ), 'no stop command for a stale own state'


def test_policy_that_contradicts_a_parameter_fails_fast(ros, flock_policy):
    with pytest.raises(ConfigError) as exc:
        _agent(ros, id=0, robots=3, policy=str(flock_policy), k=5)
    assert "parameter 'k' = 5" in str(exc.value) and 'k = 6' in str(exc.value)
    with pytest.raises(ConfigError, match=r"parameter 'tau' = 2 contradicts .* tau = 0"):
        _agent(ros, id=0, robots=3, policy=str(flock_policy), tau=2)
    with pytest.raises(ConfigError, match=r"parameter 'd_cr' = 4.0 contradicts .* d_cr = 5.0"):
        _agent(ros, id=0, robots=3, policy=str(flock_policy), d_cr=4.0)


def _env(domain):
    env = dict(os.environ)
    env.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONUNBUFFERED='1')
    return env


@pytest.mark.parametrize('case', ['missing', 'corrupt', 'bad_parameter'])
def test_agent_executable_refuses_a_bad_policy_or_parameter(tmp_path, case, ros_domain_id):
    if case == 'missing':
        args, expect = ['-p', f'policy:={tmp_path}/nope.pt'], 'nope.pt: no such file'
    elif case == 'corrupt':
        bad = tmp_path / 'corrupt.pt'
        bad.write_bytes(b'PK\x03\x04 this is not a TorchScript archive')
        args, expect = ['-p', f'policy:={bad}'], 'not a readable TorchScript archive'
    else:
        args, expect = ['-p', 'control_rate:=-5.0'], "parameter 'control_rate' = -5.0 is out of range"
    proc = subprocess.run(
        [sys.executable, '-m', 'knode_swarm_ros.nodes.agent', '--ros-args', '-p', 'id:=0', *args],
        env=_env(ros_domain_id),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2, proc.stderr
    assert expect in proc.stderr and 'Traceback' not in proc.stderr


def test_agent_starts_with_the_shipped_params_file_and_stops_on_sigint(tmp_path, ros_domain_id):
    from knode_swarm_ros.core.policy_io import shipped_policy_path

    assert shipped_policy_path('flock2d').is_file()  # the policy ships: PolicyError if not
    log = tmp_path / 'agent.log'
    with open(log, 'wb') as out:
        proc = subprocess.Popen(
            [
                sys.executable,
                '-m',
                'knode_swarm_ros.nodes.agent',
                '--ros-args',
                '-p',
                'id:=3',
                '--params-file',
                str(REPO / 'config' / 'agent_flock2d.yaml'),
            ],
            env=_env(ros_domain_id),
            stdout=out,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
    try:
        deadline = time.monotonic() + 90
        while time.monotonic() < deadline and proc.poll() is None and 'robot 3 of 10' not in log.read_text():
            time.sleep(0.1)  # polling a condition (the log line), not a synchronising sleep
        text = log.read_text()
        assert proc.poll() is None, f'agent exited with {proc.returncode}:\n{text}'
        assert '[agent_3]' in text and 'publishing /robot_3/cmd_accel' in text
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=20) == 0, log.read_text()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_recorder_writes_what_it_heard_and_publishes_metrics(ros, tmp_path):
    from knode_swarm_ros.core import load_trajectories
    from knode_swarm_ros.logic.common import status_json
    from knode_swarm_ros.nodes.recorder.node import RecorderNode

    out = tmp_path / 'rec.npz'
    recorder = ros.add(
        RecorderNode(
            'recorder',
            context=ros.context,
            parameter_overrides=[
                Parameter('robots', value=3),
                Parameter('output', value=str(out)),
                Parameter('metrics_rate', value=1000.0),
            ],
        )
    )
    io = ros.node('test_sim')
    pubs = {r: io.create_publisher(Odometry, f'robot_{r}/odom', qos.ODOM) for r in range(3)}
    status = io.create_publisher(String, 'simulator/status', qos.STATUS)
    avd, progress = [], []
    io.create_subscription(Float64, 'recorder/avd', lambda m: avd.append(m.data), qos.METRICS)
    io.create_subscription(Int64, 'recorder/progress', lambda m: progress.append(m.data), qos.PROGRESS)
    rng = np.random.default_rng(0)
    frames = rng.normal(size=(5, 3, 4))

    def publish():  # every frame again until the recorder has them all (duplicates are ignored)
        for t in range(5):
            for r in range(3):
                pubs[r].publish(state_to_odom(r, t * 10_000_000, frames[t, r], 'flock2d'))

    assert ros.spin_until(
        lambda: recorder.frames.progress == 4 and progress and progress[-1] == 4 and avd, each=publish
    )
    status.publish(
        String(
            data=status_json(
                phase='done',
                final_step=4,
                publish_every=1,
                dt=0.01,
                scenario='flock2d',
                robots=3,
                mode='lockstep',
            )
        )
    )
    assert ros.spin_until(lambda: recorder.finished.done())
    assert recorder.exit_code == 0 and out.is_file()
    data = load_trajectories(out)
    assert np.array_equal(data.states[0], frames) and data.dt == pytest.approx(0.01)
    assert data.meta['interrupted'] is False and data.meta['source']['mode'] == 'lockstep'


def test_simulator_refuses_an_agent_whose_policy_steps_at_another_dt(ros):
    """A simulator dt that differs from the policy's no longer runs to the end."""
    from knode_swarm_ros.logic.common import status_json
    from knode_swarm_ros.nodes.simulator.node import SimulatorNode

    sim = ros.add(
        SimulatorNode(
            'simulator',
            context=ros.context,
            parameter_overrides=[
                Parameter('robots', value=2),
                Parameter('dt', value=0.02),
                Parameter('steps', value=10),
            ],
        )
    )
    io = ros.node('test_agent_status')
    status = io.create_publisher(String, 'robot_1/agent_status', qos.STATUS)

    def publish():
        status.publish(String(data=status_json(id=1, ready=False, dt=0.01)))

    assert ros.spin_until(lambda: sim.finished.done(), each=publish)
    assert sim.exit_code == 2 and sim.sim.step == 0


def test_parameter_typos_and_shadowed_values_are_refused(tmp_path, ros_domain_id):
    """A mistyped key, or -p before a --params-file that sets it again."""
    from knode_swarm_ros.nodes.common.params import shadowed_overrides

    typo = tmp_path / 'typo.yaml'
    typo.write_text('/**:\n  ros__parameters:\n    state_timout: 0.3\n')
    cases = [
        (
            ['-p', 'id:=0', '--params-file', str(typo)],
            "unknown parameter 'state_timout': did you mean 'state_timeout'?",
        ),
        (
            [
                '-p',
                'id:=0',
                '-p',
                'policy:=/x.pt',
                '--params-file',
                str(REPO / 'config' / 'agent_flock2d.yaml'),
            ],
            "parameter 'policy' is given with -p before --params-file",
        ),
    ]
    for args, expect in cases:
        proc = subprocess.run(
            [sys.executable, '-m', 'knode_swarm_ros.nodes.agent', '--ros-args', *args],
            env=_env(ros_domain_id),
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert proc.returncode == 2 and expect in proc.stderr and 'Traceback' not in proc.stderr, proc.stderr
    good = [
        'x',
        '--ros-args',
        '--params-file',
        str(REPO / 'config' / 'agent_flock2d.yaml'),
        '-p',
        'policy:=/x.pt',
    ]
    assert shadowed_overrides(good, 'agent_0') == []
    assert (
        shadowed_overrides(
            [
                'x',
                '--ros-args',
                '-p',
                'mode:=lockstep',
                '--params-file',
                str(REPO / 'config' / 'agent_flock2d.yaml'),
            ],
            'agent_0',
        )[0][0]
        == 'mode'
    )


def _foreign_odom(robot, stamp, z, yaw, twist_frame):
    """Odometry as a foreign driver publishes it: its own yaw in the pose, its own child frame
    name, angular velocity set, the twist in the body frame (REP 105) or, deviating, the world's."""
    msg = Odometry()
    msg.header.stamp = time_msg(stamp)
    msg.header.frame_id = 'world'
    msg.child_frame_id = f'robot_{robot}/base_footprint'
    msg.pose.pose.position.x, msg.pose.pose.position.y = float(z[0]), float(z[1])
    msg.pose.pose.orientation.z, msg.pose.pose.orientation.w = float(np.sin(yaw / 2)), float(np.cos(yaw / 2))
    c, s = np.cos(yaw), np.sin(yaw)
    vx, vy = (c * z[2] + s * z[3], -s * z[2] + c * z[3]) if twist_frame == 'body' else (z[2], z[3])
    msg.twist.twist.linear.x, msg.twist.twist.linear.y = float(vx), float(vy)
    msg.twist.twist.angular.z = 0.4
    return msg


@pytest.mark.parametrize('twist_frame', ['body', 'world'])
def test_foreign_odometry_in_either_twist_frame_gives_the_same_command(ros, flock_policy, twist_frame):
    """Robots facing every quadrant, publishing REP 105 body twists (agent default) or world-frame
    twists (twist_frame:=world): the agent's command is the one the core computes from the world
    states, the same in both cases."""
    from knode_swarm_ros.core import load_policy, neighbour_matrix_single

    params = dict(id=1, robots=4, policy=str(flock_policy), mode='lockstep', use_sim_time=True)
    if twist_frame == 'world':
        params['twist_frame'] = 'world'
    _agent(ros, **params)
    io = ros.node('test_io')
    pubs = {r: io.create_publisher(Odometry, f'robot_{r}/odom', qos.ODOM) for r in range(4)}
    commands = []
    io.create_subscription(AccelStamped, 'robot_1/cmd_accel', commands.append, qos.COMMAND)
    Z = np.array(
        [[0.0, 0.0, 1.0, 0.5], [0.8, 0.3, -0.7, 1.0], [1.5, -0.4, -0.5, -0.9], [2.0, 1.0, 0.6, -1.2]]
    )
    yaws = [0.4, 2.2, -2.6, -1.1]  # one robot per quadrant, none facing its velocity
    stamp = 3 * 10_000_000

    def publish():
        for r in (3, 2, 0, 1):
            pubs[r].publish(_foreign_odom(r, stamp, Z[r], yaws[r], twist_frame))

    assert ros.spin_until(lambda: commands, each=publish), 'no command from the agent'
    ns, u = msg_to_command(commands[0], 'flock2d')
    policy = load_policy(flock_policy)
    Y, mask = neighbour_matrix_single(1, Z[1], Z, 2, policy.d_cr, policy.k)
    assert mask.sum() == 4
    expected = np.clip(policy(Y[None], mask[None])[0], -10.0, 10.0)
    assert ns == stamp and np.allclose(u, expected, rtol=0, atol=1e-6)
    # Read with the wrong frame, the velocities (and so the command) would differ: the check can fail.
    Z_wrong = Z.copy()
    for r in range(4):
        c, s = np.cos(yaws[r]), np.sin(yaws[r])
        Z_wrong[r, 2:] = (c * Z[r, 2] + s * Z[r, 3], -s * Z[r, 2] + c * Z[r, 3])
    Yw, maskw = neighbour_matrix_single(1, Z_wrong[1], Z_wrong, 2, policy.d_cr, policy.k)
    assert not np.allclose(np.clip(policy(Yw[None], maskw[None])[0], -10, 10), expected, rtol=0, atol=1e-6)


def test_agent_link_model_drops_counts_and_respects_radio_range(ros, flock_policy):
    """link_loss and link_range on a realtime agent: lost and out-of-range neighbour states never
    reach the logic, everything is counted in the status, the own state is never withheld."""
    agent = _agent(
        ros,
        id=0,
        robots=3,
        policy=str(flock_policy),
        mode='realtime',
        link_loss=0.5,
        link_range=5.0,
        link_seed=3,
        state_timeout=60.0,
    )  # a loaded machine may deliver late: nothing is too old
    io = ros.node('test_io')
    pubs = {r: io.create_publisher(Odometry, f'robot_{r}/odom', qos.ODOM) for r in range(3)}
    Z = np.array([[0.0, 0.0, 1.0, 0.0], [1.0, 0.0, 0.0, 1.0], [50.0, 0.0, 0.0, 0.0]])

    def publish():
        now = agent.get_clock().now().nanoseconds
        for r in range(3):
            pubs[r].publish(state_to_odom(r, now, Z[r], 'flock2d'))

    link = agent.link.model.counters
    assert ros.spin_until(lambda: link['offered'] >= 60, each=publish, timeout=60)
    assert link['offered'] == link['out_of_range'] + link['lost'] + link['delivered']
    assert link['out_of_range'] >= link['offered'] // 2 - 2  # every state of robot 2 (robot 0 first heard)
    assert link['lost'] > 0 and link['delivered'] > 0
    assert 2 not in agent.logic.newest_ns and 1 in agent.logic.newest_ns and 0 in agent.logic.newest_ns
    status = agent._status()
    assert status['link']['lost'] == link['lost']
    with pytest.raises(ConfigError, match='link'):
        _agent(ros, id=1, robots=3, policy=str(flock_policy), mode='lockstep', link_loss=0.1)


@pytest.mark.parametrize('stamped', [True, False])
def test_agent_unicycle_mode_publishes_cmd_vel_from_the_point_ahead(ros, flock_policy, stamped):
    """command_interface unicycle: the core's acceleration command, held over one control period,
    becomes the velocity of the point 0.2 ahead of the axle, mapped to (linear.x, angular.z) at the
    robot's heading from its REP 105 Odometry (body twist, angular.z)."""
    from geometry_msgs.msg import Twist, TwistStamped

    from knode_swarm_ros.core import load_policy, neighbour_matrix_single
    from knode_swarm_ros.core.unicycle import point_ahead

    state = 'point' if stamped else 'axle'  # what the policy sees: the point 0.2 ahead, or the Odometry as is
    agent = _agent(
        ros,
        id=0,
        robots=2,
        policy=str(flock_policy),
        mode='realtime',
        control_rate=20.0,
        state_timeout=60.0,
        command_interface='unicycle',
        unicycle_stamped=stamped,
        unicycle_lookahead=0.2,
        max_linear_speed=50.0,
        max_angular_speed=500.0,
        unicycle_state=state,
    )
    io = ros.node('test_io')
    pubs = {r: io.create_publisher(Odometry, f'robot_{r}/odom', qos.ODOM) for r in range(2)}
    got = []
    io.create_subscription(TwistStamped if stamped else Twist, 'robot_0/cmd_vel', got.append, qos.COMMAND)
    yaw, speed, turn = 2.3, 0.5, 0.3
    own_world_v = speed * np.array([np.cos(yaw), np.sin(yaw)])
    Z = np.array([[0.0, 0.0, *own_world_v], [1.0, 0.5, 0.2, -0.1]])

    def publish():
        now = agent.get_clock().now().nanoseconds
        own = state_to_odom(0, now, Z[0], 'flock2d')  # position; the orientation and body twist follow
        own.pose.pose.orientation.z, own.pose.pose.orientation.w = (
            float(np.sin(yaw / 2)),
            float(np.cos(yaw / 2)),
        )
        own.twist.twist.linear.x, own.twist.twist.linear.y = speed, 0.0
        own.twist.twist.angular.z = turn
        pubs[1].publish(state_to_odom(1, now, Z[1], 'flock2d'))
        pubs[0].publish(own)

    assert ros.spin_until(lambda: len(got) >= 2 and agent.logic.ready, each=publish, timeout=60)
    policy = load_policy(flock_policy)
    pos, point_v = point_ahead(0.0, 0.0, yaw, speed, turn, 0.2)
    seen = (
        Z.copy() if state == 'axle' else np.array([[*pos, *point_v], [1.2, 0.5, 0.2, -0.1]])
    )  # robot 1: yaw 0
    Y, mask = neighbour_matrix_single(0, seen[0], seen, 2, policy.d_cr, policy.k)
    u = np.clip(policy(Y[None], mask[None])[0], -10.0, 10.0)
    want = point_v + u / 20.0
    c, s = np.cos(yaw + turn / 40.0), np.sin(yaw + turn / 40.0)  # the heading in the middle of the period
    v, w = c * want[0] + s * want[1], (-s * want[0] + c * want[1]) / 0.2
    msg = got[-1]
    twist = msg.twist if stamped else msg
    assert twist.linear.x == pytest.approx(v, abs=1e-5) and twist.angular.z == pytest.approx(w, abs=1e-4)
    assert twist.linear.y == 0.0 and twist.linear.z == 0.0
    if stamped:
        assert msg.header.frame_id == 'robot_0/base_link'
    assert agent._status()['unicycle']['periods'] >= 2
    with pytest.raises(ConfigError, match='realtime'):  # a Twist has no stamp: no lockstep
        _agent(
            ros,
            id=1,
            robots=2,
            policy=str(flock_policy),
            mode='lockstep',
            command_interface='unicycle',
            unicycle_stamped=False,
        )
    with pytest.raises(ConfigError, match='command_interface'):
        _agent(ros, id=1, robots=2, policy=str(flock_policy), command_interface='twist')


def _lifecycle(io, ros, node_name, transition=None):
    """get_state, or change_state to ``transition`` (a lifecycle_msgs Transition id), through the services."""
    from lifecycle_msgs.srv import ChangeState, GetState

    if transition is None:
        client = io.create_client(GetState, f'{node_name}/get_state')
        request = GetState.Request()
    else:
        client = io.create_client(ChangeState, f'{node_name}/change_state')
        request = ChangeState.Request()
        request.transition.id = transition
    assert ros.spin_until(lambda: client.service_is_ready(), timeout=30)
    future = client.call_async(request)
    assert ros.spin_until(lambda: future.done(), timeout=30)
    io.destroy_client(client)
    result = future.result()
    return result.current_state.label if transition is None else result.success


def test_managed_agent_through_the_lifecycle_services(ros, flock_policy):
    """managed:=true: unconfigured until configured, quiet until activated, commands when active,
    on deactivate brakes an acceleration robot to rest (one saturated stop per period) and then
    publishes nothing; an unmanaged agent is active by itself."""
    from lifecycle_msgs.msg import Transition
    from rclpy.parameter import Parameter

    from knode_swarm_ros.nodes.agent.node import AgentNode

    params = dict(
        id=1,
        robots=2,
        policy=str(flock_policy),
        mode='realtime',
        control_rate=20.0,
        state_timeout=60.0,
        managed=True,
    )
    agent = ros.add(
        AgentNode(
            'agent_1',
            context=ros.context,
            parameter_overrides=[Parameter(k, value=v) for k, v in params.items()],
        )
    )
    io = ros.node('test_io')
    pubs = {r: io.create_publisher(Odometry, f'robot_{r}/odom', qos.ODOM) for r in range(2)}
    commands = []
    io.create_subscription(AccelStamped, 'robot_1/cmd_accel', commands.append, qos.COMMAND)
    Z = np.array([[0.0, 0.0, 1.0, 0.0], [0.8, 0.3, 3.0, -1.0]])

    def publish():
        now = agent.get_clock().now().nanoseconds
        for r in (0, 1):
            pubs[r].publish(state_to_odom(r, now, Z[r], 'flock2d'))

    assert _lifecycle(io, ros, 'agent_1') == 'unconfigured'
    assert _lifecycle(io, ros, 'agent_1', Transition.TRANSITION_CONFIGURE) is True
    assert _lifecycle(io, ros, 'agent_1') == 'inactive'
    assert ros.spin_until(lambda: agent.logic.ready, each=publish, timeout=30)
    ros.spin_until(lambda: False, each=publish, timeout=1.0)  # ticks happen; nothing may come out
    assert commands == [] and agent._status()['ready'] is False
    assert _lifecycle(io, ros, 'agent_1', Transition.TRANSITION_ACTIVATE) is True
    assert _lifecycle(io, ros, 'agent_1') == 'active'
    assert ros.spin_until(lambda: len(commands) >= 3, each=publish, timeout=30)
    assert agent._status()['ready'] is True
    assert _lifecycle(io, ros, 'agent_1', Transition.TRANSITION_DEACTIVATE) is True
    assert _lifecycle(io, ros, 'agent_1') == 'inactive'
    n_active = len(commands)
    # The robot still moves at (3, -1): brake commands -v/dt saturated at 10 -> (-10, 10).
    assert ros.spin_until(lambda: len(commands) >= n_active + 2, each=publish, timeout=30)
    _, u = msg_to_command(commands[-1], 'flock2d')
    assert np.allclose(u, [-10.0, 10.0])
    # Once the robot stands, the stop ends and the inactive agent goes quiet.
    Z[1, 2:] = 0.0
    assert ros.spin_until(lambda: not agent.braking, each=publish, timeout=30)
    sent = agent.stops_sent
    assert ros.spin_until(lambda: np.allclose(msg_to_command(commands[-1], 'flock2d')[1], 0.0), each=publish)
    ticks = agent.logic.counters['commands']
    assert ros.spin_until(lambda: agent.logic.counters['commands'] >= ticks + 5, each=publish)
    assert agent.stops_sent == sent  # ticks go on, nothing is published
    # Unmanaged (the default): active at once, no lifecycle manager needed.
    plain = _agent(ros, id=0, robots=2, policy=str(flock_policy), mode='realtime')
    assert plain.active and _lifecycle(io, ros, 'agent_0') == 'active'


def test_agent_publishes_its_health_on_diagnostics(ros, flock_policy):
    from diagnostic_msgs.msg import DiagnosticArray

    agent = _agent(
        ros, id=2, robots=3, policy=str(flock_policy), mode='realtime', state_timeout=60.0, status_period=0.2
    )
    io = ros.node('test_io')
    pubs = {r: io.create_publisher(Odometry, f'robot_{r}/odom', qos.ODOM) for r in range(3)}
    reports = []
    io.create_subscription(DiagnosticArray, '/diagnostics', reports.append, qos.DIAGNOSTICS)
    Z = np.array([[0.0, 0.0, 1.0, 0.0], [0.8, 0.3, 0.0, 1.0], [0.5, -0.4, -0.5, 0.5]])

    def publish():
        now = agent.get_clock().now().nanoseconds
        for r in range(3):
            pubs[r].publish(state_to_odom(r, now, Z[r], 'flock2d'))

    def healthy():
        if not reports:
            return False
        entry = reports[-1].status[0]
        values = {kv.key: kv.value for kv in entry.values}
        return values.get('heard') == '3/3' and values.get('neighbours') == '2' and entry.level == b'\x00'

    assert ros.spin_until(healthy, each=publish, timeout=60)
    entry = reports[-1].status[0]
    assert (
        entry.name == 'knode_swarm agent robot_2' and entry.hardware_id == 'robot_2' and entry.message == 'ok'
    )


def test_lockstep_unicycle_agent_answers_a_resend_with_the_same_twist(ros, flock_policy):
    """A lockstep resend of a step's command repeats the twist it answered: the acceleration
    ramp advances once per state, as in the offline study (else the swarm leaves it)."""
    from geometry_msgs.msg import TwistStamped

    from knode_swarm_ros.logic.agent.agent_logic import Command
    from knode_swarm_ros.nodes.common.conversions import time_msg

    agent = _agent(
        ros,
        id=0,
        robots=2,
        policy=str(flock_policy),
        mode='lockstep',
        command_interface='unicycle',
        max_linear_accel=1.0,
        max_angular_accel=2.0,
    )
    io = ros.node('test_io')
    got = []
    io.create_subscription(TwistStamped, 'robot_0/cmd_vel', got.append, qos.COMMAND)
    uni = agent.unicycle
    uni.observe(True, (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0), (0.5, 0.0, 0.0), (0.0, 0.0, 0.0), np.zeros(4))
    assert uni.mapper.last == (0.5, 0.0)  # the ramp starts from the robot's motion
    first = Command(1_000_000, 1, np.array([9.0, 9.0]))
    for cmd in (first, first, Command(2_000_000, 2, np.array([9.0, 9.0]))):
        uni.publish(time_msg(cmd.stamp_ns), cmd)
    assert ros.spin_until(lambda: len(got) >= 3, timeout=30)
    twists = [(m.twist.linear.x, m.twist.angular.z) for m in got]
    step = 1.0 * 0.01, 2.0 * 0.01  # the policy's dt: lockstep's control period
    assert twists[0] == twists[1] == pytest.approx((0.5 + step[0], step[1]))
    assert twists[2] == pytest.approx((0.5 + 2 * step[0], 2 * step[1])) and uni.mapper.periods == 2
