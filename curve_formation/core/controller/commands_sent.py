"""The commands a controller sent, and what they did: which one acted when (each from its
sending plus the command latency), their average through the motors' lag over a motion, and
the pose they carried the robot to. What predict_pose and the observer read.

Times in s on the controller's clock; poses in the arena frame (m, rad); commands in m/s and
rad/s.
"""

from collections import deque
from collections.abc import Iterator
import math

import numpy as np

from curve_formation.core.base.shapes import Pose
from curve_formation.core.controller.inputs import Sent
from curve_formation.core.formation.dynamics import arc_step


def driven_pose(x: float, y: float, theta: float, v: float, w: float, drift_v: float,
                drift_w: float, dt: float) -> Pose:
    """Pose after dt (s) under command (v, w), plus the drift while driven (m/s, rad/s)."""
    if dt <= 0.0:
        return x, y, theta
    if v != 0.0 or w != 0.0:
        v, w = v + drift_v, w + drift_w
    return arc_step(x, y, theta, v, w, dt)


class CommandsSent:
    """The last `size` commands sent (Sent), oldest first."""

    def __init__(self, size: int) -> None:
        self._sent: deque[Sent] = deque(maxlen=size)

    def append(self, sent: Sent) -> None:
        self._sent.append(sent)

    def __iter__(self) -> Iterator[Sent]:
        return iter(self._sent)

    def __len__(self) -> int:
        return len(self._sent)

    def acting(self, at: float, latency: float) -> Sent | None:
        """The command acting on the robot at `at`: the last sent `latency` s or more before;
        None if none is known.
        """
        acting = None
        for sent in self._sent:
            if sent.at > at - latency + 1e-9:
                break
            acting = sent
        return acting

    def first_acting_after(self, updates: int, latency: float) -> float | None:
        """When the first command sent after the observer's `updates`-th update began to act
        (its sending plus the latency); None if none was sent yet.
        """
        return next((sent.at + latency for sent in self._sent if sent.estimate >= updates),
                    None)

    def realised(self, end: float, elapsed: float, latency: float, tau: float,
                 updates: int) -> Sent | None:
        """What the wheels did on average over the `elapsed` s up to `end`: the commands sent,
        each acting from its sending plus `latency`, through the motors' first-order lag
        `tau` (0: none), as a Sent (reference and shift averaged; limited if any was; driven
        only if all were; estimate the fewest observer updates any was sent after, at most
        `updates`); None if the commands sent do not reach back that far.
        """
        begin = end - elapsed
        sent = list(self._sent)
        if not sent or sent[0].at + latency > begin:
            return None
        lag = np.array([*sent[0].reference, *sent[0].shift])   # the wheels' state
        total = np.zeros(4)
        limited, driven, estimate = False, True, updates
        for k, command in enumerate(sent):
            start = command.at + latency
            if start >= end:
                break
            stop = min(sent[k + 1].at + latency, end) if k + 1 < len(sent) else end
            target = np.array([*command.reference, *command.shift])
            before = min(max(begin, start), stop)   # the part before the interval
            span = stop - before
            if tau > 0.0:
                lag = target + (lag - target) * math.exp(-(before - start) / tau)
            if span <= 0.0:
                continue
            if tau > 0.0:
                decay = math.exp(-span / tau)
                total += target * span + (lag - target) * tau * (1.0 - decay)
                lag = target + (lag - target) * decay
            else:   # no lag: each command for the time it acts
                total += target * span
            limited = limited or command.limited
            driven = driven and command.driven
            estimate = min(estimate, command.estimate)
        mean = total / elapsed
        return Sent(end, 0.0, 0.0, (float(mean[0]), float(mean[1])),
                    (float(mean[2]), float(mean[3])), limited, driven, estimate)

    def carried(self, pose: Pose, start: float, until: float, latency: float,
                drift_v: float, drift_w: float) -> Pose:
        """The pose taken at `start` carried to `until` by the commands acting since (each
        from its sending plus `latency`) and the drift while driven (m/s, rad/s).
        """
        x, y, theta = pose
        v, w, at = 0.0, 0.0, start
        for sent in self._sent:
            acts = sent.at + latency
            if acts > start:
                x, y, theta = driven_pose(x, y, theta, v, w, drift_v, drift_w, acts - at)
                at = acts
            v, w = sent.v, sent.w
        return driven_pose(x, y, theta, v, w, drift_v, drift_w, until - at)

    def predicted(self, pose: Pose, stamp: float, received: float, now: float,
                  latency: float, longest: float, drift: tuple[float, float]) -> Pose:
        """The pose taken at `stamp` (received at `received`) carried to `now` + `latency`
        (carried). Its age is now - stamp where that lies in [0, longest], i.e. where the
        pose's source and the controller share a clock (or are synchronised); otherwise only
        the time the pose was held here (now - received) is made up for.
        """
        age = now - stamp
        if not 0.0 <= age <= longest:
            age = min(max(now - received, 0.0), longest)
        return self.carried(pose, now - age, now + latency, latency, *drift)
