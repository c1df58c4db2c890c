"""One sampler of a run's record, live or from a bag: each robot's latest pose, command and
estimate, taken at sample times.

The live monitor (nodes/monitor.py) feeds a LatestValues from its subscriptions and samples it
on its timer; the bag analysis (bags/analysis.py) feeds one the recorded messages in the order they
were received and samples it on a uniform grid (GridSampler). Both refuse the poses the
controllers refuse (outside the experiment's geofence, or not finite) and give the same
fields, so a run and the analysis of its bag measure the same thing.
"""

import math
from typing import Any

import numpy as np

from curve_formation.core.base.shapes import FloatArray
from curve_formation.core.controller.agent_config import Fence
from curve_formation.core.controller.plausibility import plausible_box, position_problem


# The fields of a row (LatestValues.row).
FIELDS = ('t', 'poses', 'commands', 'dhat', 'pose_stamps')


class LatestValues:
    """Each of n robots' latest pose (m, m, rad; world frame) with the time it was taken (s,
    the sender's stamp), command (m/s, rad/s) and disturbance estimate (m/s, m/s): NaN until
    one comes. fence: the experiment's geofence (core.controller.agent_config.geofence; None
    without one): a
    pose is believed where the controllers believe it (core.controller.plausibility.plausible_box).
    """

    def __init__(self, n: int, fence: Fence = None) -> None:
        self.box = plausible_box(fence)
        self.poses = np.full((n, 3), np.nan)
        self.pose_stamps = np.full(n, np.nan)
        self.commands = np.full((n, 2), np.nan)
        self.dhat = np.full((n, 2), np.nan)
        self.refused = 0   # poses refused as unbelievable

    def pose(self, i: int, x: float, y: float, theta: float, stamp: float) -> bool:
        """Robot i's (1-based) pose taken at `stamp` s; False (and counted) if refused."""
        if position_problem(x, y, self.box) is not None or not math.isfinite(theta):
            self.refused += 1
            return False
        self.poses[i - 1] = (x, y, theta)
        self.pose_stamps[i - 1] = stamp
        return True

    def command(self, i: int, v: float, w: float) -> None:
        self.commands[i - 1] = (v, w)

    def estimate(self, i: int, dx: float, dy: float) -> None:
        self.dhat[i - 1] = (dx, dy)

    def row(self, t: float, t0: float) -> dict[str, Any]:
        """The sample at time t (s, the receiver's clock) of a run whose t = 0 is at t0:
        t and pose_stamps in s since t = 0, the values as they are now (copies).
        """
        return {'t': t - t0, 'poses': self.poses.copy(), 'commands': self.commands.copy(),
                'dhat': self.dhat.copy(), 'pose_stamps': self.pose_stamps - t0}


class GridSampler:
    """Rows of a LatestValues every 1/hz s from t0, for values fed in the order received.

    Call `until(t)` before feeding a value received at t: the rows due before t are taken
    then (a value received exactly at a row's time is in that row). `finish(end)` takes the
    rows due before `end` and drops any taken at or after it.
    """

    def __init__(self, latest: LatestValues, hz: float) -> None:
        self.latest = latest
        self.period = 1.0 / hz
        self.t0: float | None = None
        self.rows: list[dict[str, Any]] = []

    def start(self, t0: float) -> None:
        """t = 0 (s, the receiver's clock): the first row is due then."""
        self.t0 = t0

    def until(self, t: float) -> None:
        if self.t0 is None:
            return
        while self.t0 + len(self.rows) * self.period < t:
            self.rows.append(self.latest.row(self.t0 + len(self.rows) * self.period, self.t0))

    def finish(self, end: float) -> dict[str, FloatArray]:
        """The rows before `end` (s, the receiver's clock) as arrays: {field: (R, ...)}."""
        self.until(end)
        while self.rows and self.rows[-1]['t'] + self.t0 >= end:
            self.rows.pop()
        return {key: np.array([row[key] for row in self.rows]) for key in FIELDS}
