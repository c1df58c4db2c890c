"""Each agent's AgentConfig as an experiment gives it: what a formation_controller node and
the tick pipeline build their AgentControllers from.

Units: m, s, rad; the geofence in the arena frame.
"""

import dataclasses
from typing import Any

from curve_formation.core.base.shapes import FloatArray
from curve_formation.core.config.experiment import Experiment, pose_rate, RELAY_DELIVERY
from curve_formation.core.controller.agent_config import AgentConfig, Fence


def geofence(experiment: Experiment) -> Fence:
    """(xmin, ymin, xmax, ymax) (m, arena frame) outside which a robot is stopped: the
    arena grown by safety.geofence_margin; None without an arena.
    """
    spec = experiment.spec
    if spec.arena is None:
        return None
    m = spec.safety.geofence_margin
    return (-m, -m, spec.arena.size[0] + m, spec.arena.size[1] + m)


def agent_configs(experiment: Experiment, rate_hz: float) -> list[AgentConfig]:
    """Every agent's AgentConfig (agent 1 first) from an experiment, controlled at rate_hz:
    its graph neighbours, gains, limits, safety timeouts and geofence, PC-injected
    disturbance and safety filter.
    """
    spec = experiment.spec
    on_pc = spec.disturbance.injected == 'on_pc'
    fence = geofence(experiment)
    relay = leader_relays(experiment)
    return [dataclasses.replace(AgentConfig(
        index=i, agent_count=experiment.n, neighbours=tuple(experiment.graph.in_neighbours(i)),
        pinning=experiment.graph.follower_pinning, gains=experiment.gains,
        limits=experiment.limits, rate_hz=float(rate_hz),
        pose_timeout=spec.safety.pose_timeout, neighbour_timeout=spec.safety.neighbour_timeout,
        leader_timeout=spec.safety.leader_timeout, geofence=fence,
        pc_disturbance=((float(experiment.disturbance[i - 1][0]),
                         float(experiment.disturbance[i - 1][1])) if on_pc else (0.0, 0.0)),
        avoidance=experiment.avoidance, predict_pose=spec.controller.predict_pose,
        command_latency=spec.controller.command_latency,
        feed_forward=spec.controller.feed_forward,
        min_wheel_speed=(spec.limits.min_wheel_speed or 0.0) if spec.limits else 0.0,
        motor_time_constant=(spec.limits.motor_time_constant or 0.0) if spec.limits else 0.0,
        estimate_latency=spec.controller.estimate_latency,
        estimate_motors=spec.controller.estimate_motors,
        motor_check=spec.controller.motor_check,
        leader_relay=float(relay[i - 1])), **robot_own(experiment, i))
        for i in range(1, experiment.n + 1)]


def leader_relays(experiment: Experiment) -> FloatArray:
    """(n,) s the leader's news may take to reach each agent beyond leader_timeout: a
    follower relays it with its state when its next pose comes, so each hop on the shortest
    path from the leader adds up to a pose period (config.experiment.pose_rate) and the
    delivery (RELAY_DELIVERY). A follower h hops down stops after leader_timeout + that.
    """
    hop = 1.0 / pose_rate(experiment) + RELAY_DELIVERY
    return experiment.graph.hops_from_leader().astype(float) * hop


def robot_own(experiment: Experiment, i: int) -> dict[str, Any]:
    """AgentConfig fields in which agent i's robot differs from the file's limits, as
    robots.fleet lists it: its wheel base (in its limits), motor lag and dead band.
    """
    fleet = experiment.spec.robots.fleet
    if not fleet:
        return {}
    robot = fleet[i - 1]
    own: dict[str, Any] = {}
    if robot.wheel_base is not None:
        own['limits'] = experiment.limits._replace(wheel_base=float(robot.wheel_base))
    if robot.motor_time_constant is not None:
        own['motor_time_constant'] = float(robot.motor_time_constant)
    if robot.min_wheel_speed is not None:
        own['min_wheel_speed'] = float(robot.min_wheel_speed)
    return own
