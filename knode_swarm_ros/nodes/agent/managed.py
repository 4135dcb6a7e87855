"""The agent as a ROS 2 managed (lifecycle) node (parameter ``managed``).

``managed: false`` (default): the agent configures and activates itself at start, so
``ros2 run knode_swarm_ros agent --ros-args -p id:=3`` commands on its own (its lifecycle
state then reads ``active``). ``managed: true``: it starts ``unconfigured`` and waits for the
standard lifecycle services (``<node>/get_state``, ``<node>/change_state``):

* configure: read the parameters, load and check the policy, warm it up, subscribe (states are
  buffered from here on); a bad parameter or policy fails the transition with the message in
  the log (restart the node to try again);
* activate: start commanding;
* deactivate: publish a stop, then go quiet: velocity robots get zero velocity once,
  acceleration robots brake to rest (the acceleration that cancels the velocity in one step,
  saturated at the command limit, every control period until the robot stands), unicycle robots
  brake within their acceleration limits; after that the inactive agent publishes nothing;
* cleanup: drop the policy, subscriptions and timers (back to unconfigured).

An inactive agent reports ``ready: false`` in its status, so a simulator waiting for ready
agents does not start before the swarm is activated.
"""

from __future__ import annotations

from typing import Optional

import numpy as np
from rclpy.lifecycle import TransitionCallbackReturn

from knode_swarm_ros.core.saturation import stop_command
from knode_swarm_ros.logic.common import ConfigError
from knode_swarm_ros.nodes.common.conversions import command_to_msg, time_msg

__all__ = ['ManagedAgentMixin', 'brake_command']

_REST = 1e-6  # speed below which an acceleration robot counts as standing


def brake_command(
    command: str,
    z_own: Optional[np.ndarray],
    dt: float,
    limit: Optional[float],
    velocity_slice=slice(2, 4),
    command_dim: int = 2,
) -> np.ndarray:
    """The stop command ``[m]`` of a robot whose latest state is ``z_own [d]`` (None: not heard
    yet, zero): :func:`knode_swarm_ros.core.saturation.stop_command` of its velocity
    ``z_own[velocity_slice]`` held ``dt``, saturated per axis at ``limit`` (None or 0: none)."""
    if command != 'acceleration' or z_own is None:
        return np.zeros(command_dim)
    velocity = np.asarray(z_own, dtype=np.float64)[velocity_slice]
    return stop_command(command, velocity, limit or None, dt)


class ManagedAgentMixin:
    """Lifecycle callbacks of :class:`knode_swarm_ros.nodes.agent.AgentNode` (see module doc).

    The node provides ``_setup()`` (everything configure does), ``logic``, ``spec``,
    ``cmd_pub`` and ``unicycle``; this mixin keeps ``active`` and ``braking``.
    """

    active = False
    braking = False
    configured = False
    stops_sent = 0  # stop commands published while not active

    # --- transitions ---------------------------------------------------------------
    def on_configure(self, state) -> TransitionCallbackReturn:
        if self.configured:
            return TransitionCallbackReturn.SUCCESS
        try:
            self._setup()
        except (ConfigError, ValueError) as exc:
            self.get_logger().error(f'configure failed: {exc}')
            return TransitionCallbackReturn.FAILURE
        self.configured = True
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state) -> TransitionCallbackReturn:
        self.active, self.braking = True, False
        self.get_logger().info('active: commanding')
        self._publish_status()
        return super().on_activate(state)

    def on_deactivate(self, state) -> TransitionCallbackReturn:
        self.active, self.braking = False, True
        self.get_logger().info('inactive: stopping the robot, then quiet')
        self._brake(self.get_clock().now().nanoseconds)
        self._publish_status()
        return super().on_deactivate(state)

    def on_cleanup(self, state) -> TransitionCallbackReturn:
        for name in ('control_timer', 'grace_timer', 'status_timer'):
            timer = getattr(self, name, None)
            if timer is not None:
                self.destroy_timer(timer)
        if getattr(self, '_inbox_poll', None) is not None:
            self.destroy_timer(self._inbox_poll.timer)
            self._inbox_poll = None
        for sub in getattr(self, 'odom_subs', []):
            self.destroy_subscription(sub)
        self.odom_subs = []
        if getattr(self, 'inbox', None) is not None:
            self.inbox.destroy()
            self.inbox = None
        self.configured = False
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state) -> TransitionCallbackReturn:
        if self.active:
            self.active, self.braking = False, True
            self._brake(self.get_clock().now().nanoseconds)
        return TransitionCallbackReturn.SUCCESS

    # --- what an inactive agent publishes -----------------------------------------
    def _brake(self, stamp_ns: int) -> None:
        """While braking: publish the stop command; stop braking once the robot stands."""
        if not self.braking or not self.configured:
            return
        latest = self.logic.buffer.latest(self.logic.me)
        z_own = None if latest is None else latest[1]
        stamp = max(int(stamp_ns), 0)
        self.stops_sent += 1
        if self.unicycle.enabled:
            v, w = self.unicycle.mapper.stop() if self.unicycle.yaw is not None else (0.0, 0.0)
            self.unicycle.publish_raw(time_msg(stamp), v, w)
            self.braking = (v, w) != (0.0, 0.0)
            return
        u = brake_command(
            self.spec.command,
            z_own,
            self.logic.dt,
            self.logic.limit,
            self.spec.velocity if self.spec.velocity is not None else slice(0, 0),
            self.spec.command_dim,
        )
        self.cmd_pub.publish(command_to_msg(stamp, u, self.spec))
        moving = (
            z_own is not None
            and self.spec.command == 'acceleration'
            and float(np.max(np.abs(z_own[self.spec.velocity]))) > _REST
        )
        self.braking = moving
