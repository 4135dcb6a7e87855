"""Configure every managed agent, then activate them together (``swarm --managed``).

    python -m knode_swarm_ros.nodes.lifecycle_manager --ros-args -p robots:=10 [-p timeout:=120.0]
    python -m knode_swarm_ros.nodes.lifecycle_manager --ros-args -p fleet:=fleet.yaml

Waits for ``agent_<id>/change_state`` of every robot (the fleet's ids, named in the log by the
fleet's names), asks all of them to configure (policy
loaded, checked and warmed up; they start buffering states), waits for every answer, and only
then asks all of them to activate, so that the swarm starts commanding in the same moment.
Exits 0 once every agent is active; 2 when an agent refuses to configure (its log says why);
1 on a timeout. The standard services (lifecycle_msgs ``ChangeState``) are all it uses, so any
lifecycle manager can do the same.
"""

from __future__ import annotations

import time
from typing import Dict, List

import rclpy
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState
from rclpy.node import Node

from knode_swarm_ros.logic.common import EXIT_CONFIG, EXIT_FAILURE, EXIT_OK, ConfigError, robot_id_list
from knode_swarm_ros.logic.contract.fleet import default_fleet, load_fleet
from knode_swarm_ros.nodes.common.params import declare, declare_int_array

__all__ = ['main', 'change_all']


def change_all(node: Node, clients: Dict[int, object], transition: int, deadline: float) -> List[int]:
    """Send ``transition`` to every client at once; returns the robot ids that refused it.

    Raises:
        TimeoutError: not every agent answered before ``deadline`` (monotonic seconds).
    """
    futures = {}
    for rid, client in clients.items():
        request = ChangeState.Request()
        request.transition.id = transition
        futures[rid] = client.call_async(request)
    while not all(f.done() for f in futures.values()):
        if time.monotonic() > deadline:
            raise TimeoutError(f'no answer from agents {[r for r, f in futures.items() if not f.done()]}')
        rclpy.spin_once(node, timeout_sec=0.1)
    return [rid for rid, f in futures.items() if not f.result().success]


def main(args=None) -> int:
    rclpy.init(args=args)
    node = Node('lifecycle_manager')
    code = EXIT_FAILURE
    try:
        robots = declare(
            node, 'robots', 10, 'swarm size: agents agent_0 .. agent_<robots-1>', int_range=(1, 10_000)
        )
        robot_ids = declare_int_array(node, 'robot_ids', "the swarm's robot ids (overrides 'robots')")
        timeout = declare(
            node, 'timeout', 120.0, 'seconds to wait for every agent', float_range=(0.1, 3600.0)
        )
        fleet_file = declare(node, 'fleet', '', "fleet file: its robots (overrides 'robots' and 'robot_ids')")
        fleet = load_fleet(fleet_file) if fleet_file else default_fleet(robot_id_list(robots, robot_ids))
        ids = fleet.ids

        def named(rids) -> str:
            return ', '.join(f'{fleet.name_of(r)} (agent_{r})' for r in rids)

        clients = {rid: node.create_client(ChangeState, f'agent_{rid}/change_state') for rid in ids}
        deadline = time.monotonic() + timeout
        log = node.get_logger()
        while not all(c.service_is_ready() for c in clients.values()):
            if time.monotonic() > deadline:
                missing = [rid for rid, c in clients.items() if not c.service_is_ready()]
                log.error(f'agents of {named(missing)} offer no lifecycle services after {timeout:g} s')
                return EXIT_FAILURE
            rclpy.spin_once(node, timeout_sec=0.1)
        refused = change_all(node, clients, Transition.TRANSITION_CONFIGURE, deadline)
        if refused:
            log.error(f'agents of {named(refused)} refused to configure (see their logs): nothing activated')
            code = EXIT_CONFIG
            return code
        log.info(f'all {len(ids)} agents configured: activating them together')
        refused = change_all(node, clients, Transition.TRANSITION_ACTIVATE, deadline)
        if refused:
            log.error(f'agents of {named(refused)} refused to activate')
            return EXIT_FAILURE
        log.info(f'all {len(ids)} agents active')
        code = EXIT_OK
    except TimeoutError as exc:
        node.get_logger().error(str(exc))
    except ConfigError as exc:
        node.get_logger().error(str(exc))
        code = EXIT_CONFIG
    except KeyboardInterrupt:
        code = 130
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return code
