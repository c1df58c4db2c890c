"""The curve schedule of a run as the curve server keeps it, without ROS: which curve is
published when (a curve that only begins to move announced ahead), its id and the agents'
parameters it carries, a moving curve renewed where it is, the targets re-assigned among the
robots, an observed curve taking over, and the phases as they were followed. Where the caller
knows the robots' top speeds (`robots_now`: their controllers measured their wheels), a curve
switched to is assigned by trip time where that shortens the longest trip enough
(assignment.timed_order).

The curve server (nodes/curve_server.py) publishes what it returns on /formation/curve and the
nodes' pipeline (core/sim/pipeline.py) hands the same to its controllers: one schedule for both.
Times are on the caller's clock (s); the run's t = 0 is when `begin` was called.
"""

from dataclasses import dataclass, replace

import numpy as np

from curve_formation.core.base.shapes import FloatArray
from curve_formation.core.config.experiment import ANNOUNCE_AHEAD, Experiment, Phase
from curve_formation.core.formation.assignment import reassigned, top_speeds
from curve_formation.core.formation.curve_codec import CurveClock
from curve_formation.core.formation.curves import Curve
from curve_formation.core.formation.dynamics import offset_points


@dataclass(frozen=True)
class Publication:
    """One curve message: the curve, its id, the agents' parameters s (n,), a moving curve's
    coefficient rate (Curve; points(s) in m/s; None when still) and when the curve is where
    it is (CurveClock on the schedule's clock; its run_time None before the run began).
    """

    curve: Curve
    curve_id: int
    s: FloatArray
    rate: Curve | None
    clock: CurveClock


class CurveSchedule:
    """An experiment's curve schedule, stepped by its caller (module doc)."""

    def __init__(self, experiment: Experiment, scheduled: bool = True,
                 announce_ahead: float = ANNOUNCE_AHEAD) -> None:
        """scheduled: publish the experiment's curves (False: observed curves only).
        announce_ahead: s a curve that only begins to move is published before its start.
        """
        self.experiment = experiment
        self.phases = experiment.phases if scheduled else ()
        self.announce_ahead = announce_ahead
        self.t0: float | None = None
        self.next_phase = 0
        self.next_id = 0
        self.phase: Phase | None = None   # the scheduled phase followed now (as switched to)
        self.moving_since: float | None = None   # when the moving phase began to move
        self.last: Publication | None = None
        self._start_points = offset_points(experiment.initial_poses, experiment.gains.offset)
        self.reassigned = False   # targets re-assigned since the last scheduled switch
        self.speeds: FloatArray | None = None   # the robots' top speeds (robots_now)
        self.changes: list[tuple[float, FloatArray, FloatArray]] = []
        self.followed: list[Phase] = []

    @property
    def targets(self) -> FloatArray:
        """Where the agents are headed (n, 2; m, arena frame): the targets last published;
        before any curve, the start poses' offset points.
        """
        last = self.last
        return self._start_points if last is None else last.curve.points(last.s)

    def robots_now(self, points: FloatArray | None, speeds: FloatArray | None) -> None:
        """What the caller knows of the robots now: their control points (n, 2; m, arena
        frame; None: not known), from which the first curve is assigned while none has been
        published, and their top speeds (n,; m/s, NaN where unknown: the wheels' limit),
        by which each curve switched to from then is assigned (assignment.top_speeds).
        """
        if points is not None and self.last is None:
            self._start_points = np.asarray(points, float)
        self.speeds = top_speeds(speeds, self.experiment.limits.max_wheel_speed)

    def begin(self, now: float) -> None:
        """The run's t = 0 is `now`: the schedule's times count from here."""
        self.t0 = now

    def lead(self, k: int, ahead: float | None = None) -> float:
        """How long (s) before its start phase k is published, as things are now
        (Experiment.announce_lead), by a schedule that announces `ahead` s (default its own
        announce_ahead).
        """
        current = None if self.last is None else (self.last.curve, self.last.s)
        return self.experiment.announce_lead(k, current, self.moving_since is not None,
                                             self.reassigned, self.targets,
                                             self.announce_ahead if ahead is None else ahead,
                                             self.speeds)

    def next_due(self) -> float | None:
        """When (s, the schedule's clock) the next scheduled curve is due; None when none is
        left or the run has not begun.
        """
        if self.t0 is None or self.next_phase >= len(self.phases):
            return None
        k = self.next_phase
        return self.t0 + self.phases[k].start - self.lead(k)

    def due(self, now: float) -> list[Publication]:
        """The scheduled curves due by `now`, in order, each switched to (a switch ends the
        phase followed before it).
        """
        out = []
        while self.t0 is not None and self.next_phase < len(self.phases):
            k = self.next_phase
            lead = self.lead(k)
            if self.t0 + self.phases[k].start - lead > now:
                break
            phase = self.experiment.switched_to(self.phases[k], self.reassigned, self.targets,
                                                self.speeds)
            self._close()
            self.next_phase, self.reassigned, self.phase = k + 1, False, phase
            # A moving curve begins to move when it is published, or, announced ahead, at
            # its scheduled start.
            begins = self.t0 + phase.start if lead > 0 else now
            self.moving_since = begins if phase.motion is not None else None
            rate = None if phase.motion is None else phase.motion.rate(phase.curve, 0.0)
            out.append(self._publish(phase.curve, phase.s, rate, begins))
        return out

    def renewal(self, now: float) -> Publication | None:
        """The moving curve where it is at `now`, with its rate (same id); None when nothing
        moves, or before an announced curve begins to move.
        """
        phase, last = self.phase, self.last
        if phase is None or phase.motion is None or self.moving_since is None or last is None:
            return None
        tau = now - self.moving_since
        if tau < 0:
            return None
        return self._publish(phase.motion.curve(phase.curve, tau), last.s,
                             phase.motion.rate(phase.curve, tau), now, tau, last.curve_id)

    def reassign(self, points: FloatArray, now: float) -> Publication | None:
        """The last curve again (as it was published, same id) with its targets re-assigned
        among the agents headed from `points` (n, 2; m, arena frame), when that shortens
        their squared trips enough (assignment.reassigned); None when they are kept.
        """
        last = self.last
        if last is None:
            return None
        new = reassigned(last.curve, last.s, points)
        if new is last.s:
            return None
        self.reassigned = True
        if self.phase is not None:
            self.changes.append((now - (self.t0 or 0.0), new, self.phase.curve.points(new)))
        return self._publish(last.curve, new, last.rate, last.clock.valid_at,
                             last.clock.moving_for, last.curve_id)

    def observed(self, curve: Curve, s: FloatArray, now: float) -> Publication:
        """An observed curve (fitted from the camera's view) as the next curve, still: it
        ends the phase followed, a moving one too.
        """
        self._close()
        self.phase, self.moving_since = None, None
        return self._publish(curve, s, None, now)

    def close(self) -> tuple[Phase, ...]:
        """The run is over: the scheduled phases as they were followed (re-assignments in
        Phase.changes, s since t = 0).
        """
        self._close()
        self.phase = None
        return tuple(self.followed)

    def _close(self) -> None:
        if self.phase is not None:
            self.followed.append(replace(self.phase, changes=tuple(self.changes)))
        self.changes = []

    def _publish(self, curve: Curve, s: FloatArray, rate: Curve | None, valid_at: float,
                 moving_for: float = 0.0, curve_id: int | None = None) -> Publication:
        if curve_id is None:
            curve_id, self.next_id = self.next_id, self.next_id + 1
        run_time = None if self.t0 is None else max(valid_at - self.t0, 0.0)
        self.last = Publication(curve, curve_id, s, rate,
                                CurveClock(valid_at, moving_for, run_time))
        return self.last
