"""One agent's static settings (AgentConfig) and how an experiment gives them: what a
formation_controller node and the tick pipeline build their AgentControllers from.

Units: m, s, rad; the geofence in the arena frame.
"""

from dataclasses import dataclass
from functools import cached_property
from typing import Optional

from curve_formation.core.base.shapes import Command
from curve_formation.core.controller.gains import Gains, Law
from curve_formation.core.controller.inputs import shared_clock
from curve_formation.core.controller.limits import NO_LIMITS, WheelLimits
from curve_formation.core.controller.safety import Avoidance, AVOIDANCE_OFF
from curve_formation.core.controller.settings import default, DEFAULT_RATE_HZ


# (xmin, ymin, xmax, ymax), arena frame (m); None: no fence.
Fence = Optional[tuple[float, float, float, float]]


@dataclass(frozen=True)
class AgentConfig:
    """Static settings of one agent (index 1-based; agent 1 is the leader): each as
    controller.settings declares it (units, meaning, default), plus the agent's place in the
    graph, its control rate (Hz), geofence (arena frame, m) and a PC-injected disturbance.
    """

    index: int
    agent_count: int
    # ((j, a_ij), ...) in-neighbours, empty for the leader
    neighbours: tuple[tuple[int, float], ...] = ()
    pinning: float = default('graph.pinning')   # a follower's weight b on its own error
    gains: Gains = Gains(default('controller.k1'), default('controller.k2'),
                         default('controller.offset'))
    limits: WheelLimits = NO_LIMITS
    rate_hz: float = DEFAULT_RATE_HZ
    pose_timeout: float = default('safety.pose_timeout')
    neighbour_timeout: float = default('safety.neighbour_timeout')
    leader_timeout: float = default('safety.leader_timeout')
    # s the leader's news may take on its way here beyond leader_timeout: each hop from the
    # leader relays it with the next pose (config.agents.leader_relay)
    leader_relay: float = 0.0
    geofence: Fence = None
    pc_disturbance: Command = (0.0, 0.0)  # added to the command before the limits (m/s, rad/s)
    avoidance: Avoidance = AVOIDANCE_OFF   # the safety filter, from every robot's pose
    predict_pose: bool = default('controller.predict_pose')
    command_latency: float = default('controller.command_latency')
    feed_forward: bool = default('controller.feed_forward')
    min_wheel_speed: float = default('limits.min_wheel_speed')
    motor_time_constant: float = default('limits.motor_time_constant')
    estimate_latency: bool = default('controller.estimate_latency')
    estimate_motors: bool = default('controller.estimate_motors')
    motor_check: bool = default('controller.motor_check')
    # The control step (step.agent_step) compiled by numba as in the batch simulator:
    # the same source, about 15x faster a tick; loading it costs ~0.7 s and ~65 MB.
    compiled: bool = False

    @property
    def shared_clock(self) -> float:
        """s: the longest a stamp on this controller's clock lags its receipt
        (inputs.shared_clock of pose_timeout).
        """
        return shared_clock(self.pose_timeout)

    @property
    def is_leader(self) -> bool:
        """The leader is the agent that receives from nobody."""
        return not self.neighbours

    @cached_property
    def law(self) -> Law:
        """The control.Law of this agent's ticks (built once: the settings are frozen)."""
        return self.gains.tick_law(self.rate_hz, on_pc=any(self.pc_disturbance))
