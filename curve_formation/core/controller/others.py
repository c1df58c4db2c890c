"""Every robot's pose as one controller knows it, for its safety filter: the latest (a robot
not seen keeps its last known pose) and carried ahead at the robots' recent velocities to
when a late command acts.

Poses (n, 3) in the arena frame (m, rad); times in s on the controller's clock.
"""

from collections import deque
import math

import numpy as np

from curve_formation.core.base.shapes import FloatArray
from curve_formation.core.controller.inputs import MAX_PREDICTION, NO_OTHERS


# How far back (s) the other robots' poses are kept to measure their velocities (ahead)
OTHERS_KEPT = 0.2


class OtherRobots:
    """The other robots' poses, as given to update()."""

    def __init__(self) -> None:
        self.poses: FloatArray = NO_OTHERS   # every robot's pose (n, 3)
        self.received: float | None = None
        # (when taken, poses (n, 3); NaN rows: not seen) of the last OTHERS_KEPT s
        self.seen: deque[tuple[float, FloatArray]] = deque()

    def update(self, given: FloatArray, taken: float, received: float) -> None:
        """Poses (n, 3; NaN rows: not seen) taken at `taken`, received at `received`."""
        seen = np.isfinite(given)
        if self.poses is not NO_OTHERS:
            given = np.where(seen, given, self.poses)
        self.poses, self.received = given, received
        kept = self.seen
        if kept and taken <= kept[-1][0]:
            kept.clear()   # a pose older than the last: start again
        kept.append((taken, np.where(seen, given, np.nan)))
        while taken - kept[0][0] > OTHERS_KEPT:
            kept.popleft()

    def ahead(self, at: float, latency: float, max_wheel_speed: float) -> FloatArray:
        """Every robot's pose (n, 3) carried from when it was taken to `at` at its velocity
        over the last OTHERS_KEPT s (no faster than max_wheel_speed, m/s; zero for a robot
        not seen at both ends), at most MAX_PREDICTION + latency s.
        """
        kept = self.seen
        if len(kept) < 2 or kept[-1][0] - kept[0][0] <= 0.0:
            return self.poses
        (start, first), (end, last) = kept[0], kept[-1]
        return carried_ahead(self.poses, first, last, end - start,
                             min(max(at - end, 0.0), MAX_PREDICTION + latency),
                             max_wheel_speed)


def carried_ahead(poses: FloatArray, first: FloatArray, last: FloatArray, span: float,
                  ahead_by: float, max_wheel_speed: float) -> FloatArray:
    """poses (n, 3) carried `ahead_by` s at each robot's velocity from `first` to `last`
    (n, 3; `span` s apart, > 0), no faster than max_wheel_speed (m/s; zero for a robot not
    seen at both ends): what the controllers and the batch simulator's kernel use.
    """
    ahead = poses.copy()
    for i in range(poses.shape[0]):
        vx = (last[i, 0] - first[i, 0]) / span
        vy = (last[i, 1] - first[i, 1]) / span
        if not (math.isfinite(vx) and math.isfinite(vy)):
            continue
        speed = math.hypot(vx, vy)
        if 0.0 < max_wheel_speed < math.inf and speed > max_wheel_speed:
            vx, vy = vx * max_wheel_speed / speed, vy * max_wheel_speed / speed
        ahead[i, 0] += vx * ahead_by
        ahead[i, 1] += vy * ahead_by
    return ahead
