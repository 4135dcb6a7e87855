"""The monitor, the lifecycle manager and the unicycle output speak a fleet's names, topics and
types (docs/ros.md, "Your own fleet"), in this process on an isolated ROS domain."""

import time

import numpy as np
import pytest
import rclpy
import yaml
from geometry_msgs.msg import PoseStamped, Twist
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter

from knode_swarm_ros.nodes.common import qos

pytestmark = pytest.mark.ros


@pytest.fixture
def ros(monkeypatch, ros_domain_id):
    """An rclpy context on a claimed domain, localhost only, with an executor; shut down afterwards."""
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    monkeypatch.setenv('ROS_DOMAIN_ID', str(ros_domain_id))
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=ros_domain_id)
    executor = SingleThreadedExecutor(context=context)
    nodes = []

    def add(node):
        nodes.append(node)
        executor.add_node(node)
        return node

    def spin_until(condition, timeout=20.0, each=None):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if each is not None:
                each()
            executor.spin_once(timeout_sec=0.05)
            if condition():
                return True
        return False

    yield type(
        'Ros', (), {'context': context, 'add': staticmethod(add), 'spin_until': staticmethod(spin_until)}
    )
    for node in nodes:
        executor.remove_node(node)
        node.destroy_node()
    executor.shutdown()
    rclpy.try_shutdown(context=context)


def _write(tmp_path, data):
    path = tmp_path / 'fleet.yaml'
    path.write_text(yaml.safe_dump(data))
    return str(path)


def test_the_monitor_reads_a_fleets_poses_and_estimates_their_velocities(ros, tmp_path):
    from knode_swarm_ros.nodes.monitor.node import MonitorNode

    fleet = _write(
        tmp_path,
        {
            'robots': {'cf231': {'id': 4}, 'cf5': {'id': 9}},
            'state': {'topic': '/mocap/{name}/pose', 'type': 'pose', 'velocity_window': 3},
        },
    )
    monitor = ros.add(
        MonitorNode(
            'monitor',
            context=ros.context,
            parameter_overrides=[Parameter('fleet', value=fleet), Parameter('web', value=False)],
        )
    )
    assert monitor.watch.ids == [4, 9]
    io = ros.add(Node('test_io', context=ros.context))
    pubs = {
        rid: io.create_publisher(PoseStamped, f'/mocap/{name}/pose', qos.ODOM)
        for name, rid in (('cf231', 4), ('cf5', 9))
    }
    velocity = {4: np.array([0.5, -0.2]), 9: np.array([0.0, 0.3])}
    sent = [0]

    def publish():  # a constant velocity at 100 Hz of stamps: the fit is exact from the second pose
        k = sent[0]
        sent[0] += 1
        for rid, pub in pubs.items():
            msg = PoseStamped()
            ns = k * 10_000_000
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(ns, 1_000_000_000)
            p = np.array([float(rid), 1.0]) + velocity[rid] * k * 0.01
            msg.pose.position.x, msg.pose.position.y = float(p[0]), float(p[1])
            msg.pose.orientation.w = 1.0
            pub.publish(msg)

    def estimated():
        monitor._take_states()
        states = monitor.watch.states
        return sent[0] > 5 and all(
            np.allclose(states[i, 2:], velocity[rid], atol=1e-9) for i, rid in enumerate((4, 9))
        )

    assert ros.spin_until(estimated, each=publish)
    # the agents' health names the fleet's robots (hardware_id), mapped back to their ids
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus

    monitor._on_diagnostics(
        DiagnosticArray(
            status=[
                DiagnosticStatus(level=b'\x01', hardware_id='cf5'),
                DiagnosticStatus(level=b'\x02', hardware_id='cf7'),
            ]
        )
    )
    assert monitor.watch.levels.tolist() == [
        -1,
        1,
    ]  # cf231 (id 4) never reported, cf5 (id 9) WARN, cf7 unknown


def test_the_unicycle_output_takes_the_fleets_topic_frame_and_type(ros, tmp_path, untrained_policies):
    from knode_swarm_ros.nodes.agent.node import AgentNode

    fleet = _write(
        tmp_path,
        {
            'robots': {'tb4_1': {'id': 1}, 'tb4_2': {'id': 2}},
            'state': {'topic': 'odom', 'type': 'odometry'},
            'command': {'topic': 'cmd_vel', 'type': 'twist', 'interface': 'unicycle'},
        },
    )
    overrides = {
        'fleet': fleet,
        'name': 'tb4_2',
        'policy': str(untrained_policies['flock2d']),
        'mode': 'realtime',
        'control_rate': 20.0,
    }
    agent = ros.add(
        AgentNode(
            'agent_2',
            context=ros.context,
            parameter_overrides=[Parameter(k, value=v) for k, v in overrides.items()],
        )
    )
    assert agent.unicycle.enabled  # the fleet's interface turns it on
    assert agent.unicycle.publisher.topic_name == '/tb4_2/cmd_vel' and agent.unicycle.msg_type is Twist
    assert agent.unicycle.frame == 'tb4_2/base_link'
