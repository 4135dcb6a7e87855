"""Per-agent /diagnostics: the ROS-free judgement (knode_swarm_ros/nodes/agent/health.py)."""

import rclpy  # noqa: F401  (a broken install must fail, not skip)

from knode_swarm_ros.logic.agent.agent_logic import DROP_REASONS
from knode_swarm_ros.nodes.agent.health import ERROR, OK, WARN, assess


def _status(commands=100, clipped=0, lifecycle='active', link=None, **drops):
    counters = {'commands': commands, 'clipped': clipped, **{r: 0 for r in DROP_REASONS}, **drops}
    out = {'counters': counters, 'heard': 5, 'robots': 6, 'lifecycle': lifecycle}
    if link:
        out['link'] = link
    return out


def test_healthy_agent_is_ok_with_rates_and_drops():
    level, message, values = assess(
        _status(commands=120, too_old=3), {'commands': 20, 'clipped': 0}, 5.0, 0.02, 0.5, 4
    )
    v = dict(values)
    assert (level, message) == (OK, 'ok')
    assert v['command_rate_hz'] == '20.00' and v['neighbours'] == '4' and v['heard'] == '5/6'
    assert v['drops_too_old'] == '3' and v['own_state_age_s'] == '0.020' and v['saturated_share'] == '0.000'


def test_stale_own_state_saturation_and_inactivity_warn_and_no_state_is_an_error():
    level, message, _ = assess(_status(), {'commands': 90}, 1.0, 0.9, 0.5, 2)
    assert level == WARN and 'stale' in message
    level, message, values = assess(
        _status(commands=110, clipped=48), {'commands': 50, 'clipped': 0}, 1.0, 0.0, 0.5, 2
    )
    assert level == WARN and 'saturated 80 %' in message and dict(values)['saturated_share'] == '0.800'
    assert (
        assess(_status(commands=110, clipped=20), {'commands': 50, 'clipped': 0}, 1.0, 0.0, 0.5, 2)[0] == OK
    )
    level, message, _ = assess(_status(lifecycle='inactive'), {}, 1.0, 0.1, 0.5, 2)
    assert level == WARN and 'not active' in message
    assert assess(_status(), {}, 1.0, None, 0.5, 0)[0] == ERROR
    values = dict(assess(_status(link={'lost': 7, 'offered': 70}), {}, 1.0, 0.0, 0.5, 1)[2])
    assert values['link_lost'] == '7' and values['link_offered'] == '70'
