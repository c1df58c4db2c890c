"""What a robot's controller takes in and gives out, free of ROS: its inputs' freshness and
clocks (StampClock), the commands it sent (Sent), its outcome per tick (Tick) and what it
tells its out-neighbours (State).

Times in s: stamps on their source's clock, `received`/`at` on this controller's clock.
"""

from dataclasses import dataclass
import math
from typing import NamedTuple, Optional

import numpy as np

from curve_formation.core.base.shapes import Command, Point, Pose


NO_OTHERS = np.zeros((0, 3))
# Longest a pose is carried forward (s): a camera pipeline's latency is well below it, a
# stamp older than it says the clocks disagree (predict_pose).
MAX_PREDICTION = 0.25


def shared_clock(pose_timeout: float) -> float:
    """s: the longest a stamp on a controller's clock lags its receipt (shares_clock): a
    pose older than pose_timeout (s) stops the robot anyway, and none is carried forward
    further than MAX_PREDICTION.
    """
    return min(pose_timeout, MAX_PREDICTION)


def shares_clock(lag: float, within: float) -> bool:
    """Whether a stamp `lag` s before its receipt (receipt minus stamp, both as read) was
    made on this controller's clock, or one synchronised with it: the lag lies in
    [0, within]. A source on another clock (a host without time sync) is off by more. The
    controller's `within` is AgentConfig.shared_clock; plain math that numba compiles.
    Two other judgements of clocks are not this one: a moving curve's valid_at is taken
    within leader_timeout either side of its receipt (an announced curve holds ahead of it,
    AgentController.set_curve), and a recording's pose stamps within metrics.MAX_STAMP_GAP of
    their samples (offline, where a sample is up to a camera frame late).
    """
    return 0.0 <= lag <= within


def is_stale(stamp: float | None, now: float, timeout: float) -> bool:
    """True when an input stamped `stamp` (s, None if never received) is older than timeout."""
    return stamp is None or now - stamp > timeout


def all_finite(*values: float) -> bool:
    """True when every value is a finite number."""
    return all(math.isfinite(v) for v in values)


def receipt(stamp: float, received: float | None) -> float:
    """When an input was received (s, this controller's clock): `received`, else its stamp."""
    return stamp if received is None else received


class StampClock:
    """A source's stamps on this controller's clock, judged from the smallest lag (receipt
    minus stamp, s) seen so far: the stamp itself where that lag is 0 to `shared` s (the
    source shares this clock), else the stamp plus that lag (another clock: dated as if it
    came as fast as the fastest). A message held in a queue keeps its stamp's date, so it
    is as old as it is, where a per-message rule could not tell it from another clock.
    """

    def __init__(self, shared: float) -> None:
        self.shared = shared
        self.floor = math.inf

    def date(self, stamp: float, received: float) -> float:
        """When the stamp was (s, this clock), counting this message's lag."""
        self.floor = min(self.floor, received - stamp)
        return stamp if shares_clock(self.floor, self.shared) else stamp + self.floor


@dataclass
class Tick:
    """Outcome of one control step. v, w (m/s, rad/s) are what to send; 0, 0 when stopped."""

    v: float = 0.0
    w: float = 0.0
    stopped: Optional[str] = None
    error: Optional[Point] = None     # own e_i (m), published for out-neighbours
    error_stamp: Optional[float] = None
    curve_id: Optional[int] = None
    dhat: tuple[float, float] = (0.0, 0.0)
    feedback: Optional[Point] = None
    # ((j, stamp s), ...) of the in-neighbour states used
    neighbour_stamps: tuple[tuple[int, Optional[float]], ...] = ()
    filtered: bool = False            # the safety filter changed the law's command
    pose: Optional[Pose] = None       # the pose the law used (predicted, with predict_pose)
    checking: bool = False            # a tick of the motor check, not of the law


@dataclass(frozen=True)
class State:
    """What an agent tells its out-neighbours.

    error e_i (m), curve id, pose stamp (s, the pose source's clock), and the age of the newest
    news of the leader it has (s, when the pose was taken: negative, down to -MAX_PREDICTION,
    for news that came after; None before any news).
    """

    error: Point
    curve_id: int
    stamp: float
    leader_age: Optional[float]


class Sent(NamedTuple):
    """A command as sent at `at` (s, the controller's clock): (v, w) (m/s, rad/s); the
    observer's reference and the safety filter's shift of it, and whether the wheel limits
    cut it by more than observer.RAY_CLIPPED (observer.observe); driven: False for a stop
    (motors off, no drift).
    """

    at: float
    v: float
    w: float
    reference: Command
    shift: Command
    limited: bool
    driven: bool
    estimate: int = 0   # the observer's updates made before it (AgentController.updates)


@dataclass
class Neighbour:
    """An in-neighbour's last state: its error (m), curve id, pose stamp and receipt."""

    error: Point = (0.0, 0.0)
    curve_id: Optional[int] = None
    stamp: Optional[float] = None       # s, the sender's pose source's clock
    received: Optional[float] = None    # s, this controller's clock
