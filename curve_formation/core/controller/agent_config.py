"""One agent's static settings (AgentConfig) and how an experiment gives them: what a
formation_controller node and the tick pipeline build their AgentControllers from.

Units: m, s, rad; the geofence in the arena frame.
"""

from dataclasses import dataclass
from functools import cached_property
from typing import Optional

from curve_formation.core.base.shapes import Command
from curve_formation.core.controller.gains import Gains, Law
from curve_formation.core.controller.limits import NO_LIMITS, WheelLimits
from curve_formation.core.controller.safety import Avoidance, AVOIDANCE_OFF


# (xmin, ymin, xmax, ymax), arena frame (m); None: no fence.
Fence = Optional[tuple[float, float, float, float]]


@dataclass(frozen=True)
class AgentConfig:
    """Static settings of one agent (index 1-based; agent 1 is the leader)."""

    index: int
    agent_count: int
    # ((j, a_ij), ...) in-neighbours, empty for the leader
    neighbours: tuple[tuple[int, float], ...] = ()
    pinning: float = 0.0            # a follower's weight b on its own error (DirectedGraph)
    gains: Gains = Gains(1.0, 1.0, 0.01)
    limits: WheelLimits = NO_LIMITS
    rate_hz: float = 10.0
    pose_timeout: float = 0.5       # s
    neighbour_timeout: float = 0.5  # s
    leader_timeout: float = 1.0     # s without news from the leader (followers)
    geofence: Fence = None
    pc_disturbance: Command = (0.0, 0.0)  # added to the command before the limits (m/s, rad/s)
    avoidance: Avoidance = AVOIDANCE_OFF   # the safety filter, from every robot's pose
    predict_pose: bool = False      # carry the pose forward to the tick (AgentController)
    # s from a command leaving this controller to the robot's wheels acting on it (the link's
    # delay): predict_pose carries the pose to when this tick's command acts, the observer
    # compares the motion with the command acting on it then
    command_latency: float = 0.0
    feed_forward: bool = True       # add a moving curve's target velocity to the command
    # m/s: a wheel commanded slower than this stays still (the motors' dead band, told): the
    # observer expects that motion, not the command (0: no dead band)
    min_wheel_speed: float = 0.0
    # s: the wheels follow their commands with this first-order lag (the motors', told): the
    # observer compares each measured motion with the commands' realised average over it
    # (each from its sending plus command_latency, through the lag); 0: the command acting
    # from the previous tick on
    motor_time_constant: float = 0.0
    # estimate command_latency online from the commands sent and the poses measured
    # (core.controller.link_estimate.OnlineLatency), starting from command_latency
    estimate_latency: bool = False
    # The control step (step.agent_step) compiled by numba as in the batch simulator:
    # the same source, about 15x faster a tick; loading it costs ~0.7 s and ~65 MB.
    compiled: bool = False

    @property
    def is_leader(self) -> bool:
        """The leader is the agent that receives from nobody."""
        return not self.neighbours

    @cached_property
    def law(self) -> Law:
        """The control.Law of this agent's ticks (built once: the settings are frozen)."""
        return self.gains.tick_law(self.rate_hz, on_pc=any(self.pc_disturbance))
