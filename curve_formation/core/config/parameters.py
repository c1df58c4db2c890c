"""An agent's settings (core.controller.agent_config.AgentConfig) as the flat parameters of
the node that runs it, ROS-free: what the launcher writes into a controller's parameters
file. The node reads them back (nodes/formation_controller.agent_config, which validates
them); a test checks the round trip for every agent of every shipped experiment. A limit
that is not set is infinite here as everywhere (`.inf` in a parameters file).
"""

from typing import Any

from curve_formation.core.controller.agent_config import AgentConfig


def node_parameters(config: AgentConfig) -> dict[str, Any]:
    """The parameters {name: value} of a node that runs AgentConfig `config`: agent_config of
    them gives `config` back (a test checks it for every agent of every shipped experiment).
    Empty lists are left out (a ROS parameter needs a type).
    """
    gains, limits, av = config.gains, config.limits, config.avoidance

    params = {
        'index': config.index, 'agent_count': config.agent_count,
        'role': 'leader' if config.is_leader else 'follower',
        'pinning': float(config.pinning),
        'k1': float(gains.k1), 'k2': float(gains.k2), 'offset': float(gains.offset),
        'rate_hz': float(config.rate_hz), 'law': gains.law,
        'adaptation': [float(g) for g in gains.adaptation],
        'observer_rate': float(gains.observer_rate),
        'observer_growth': float(gains.observer_growth),
        'tail_radius': float(gains.tail_radius), 'tail_gain': float(gains.tail_gain),
        'reverse': bool(gains.reverse),
        'heading': 'sampled' if gains.sampled_heading else 'paper',
        'wheel_base': float(limits.wheel_base), 'max_wheel_speed': float(limits.max_wheel_speed),
        'max_angular_rate': float(limits.max_angular_rate),
        'max_linear_accel': float(limits.max_linear_accel),
        'max_angular_accel': float(limits.max_angular_accel),
        'pose_timeout': float(config.pose_timeout),
        'neighbour_timeout': float(config.neighbour_timeout),
        'leader_timeout': float(config.leader_timeout),
        'leader_relay': float(config.leader_relay),
        'geofence': [float(v) for v in config.geofence or ()],
        'pc_disturbance': [float(v) for v in config.pc_disturbance],
        'in_neighbours': [int(j) for j, _ in config.neighbours],
        'weights': [float(w) for _, w in config.neighbours],
        'predict_pose': bool(config.predict_pose),
        'command_latency': float(config.command_latency),
        'feed_forward': bool(config.feed_forward),
        'min_wheel_speed': float(config.min_wheel_speed),
        'motor_time_constant': float(config.motor_time_constant),
        'observer_order': int(gains.observer_order),
        'estimate_latency': bool(config.estimate_latency),
        'estimate_motors': bool(config.estimate_motors),
        'motor_check': bool(config.motor_check),
        'compiled_law': bool(config.compiled),
    }
    if av.on:
        params.update({'avoidance': True, 'radius': float(av.radius),
                       'avoidance_margin': float(av.margin), 'avoidance_rate': float(av.rate),
                       'passing': float(av.passing), 'passing_range': float(av.passing_range),
                       'avoidance_drift': float(av.drift),
                       'arena': [float(av.width), float(av.height)] if av.width > 0 else []})
    return {name: value for name, value in params.items() if value != []}
