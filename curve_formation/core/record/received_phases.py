"""The phases a run followed, rebuilt from the curve messages it received (a bag's, the
monitor's), with the schedule's fits where a received curve is the scheduled one.

Times in s since the first curve.
"""

from collections.abc import Sequence
import dataclasses
import math

import numpy as np
from numpy.typing import ArrayLike

from curve_formation.core.config.experiment import Experiment, Phase
from curve_formation.core.formation.curve_codec import CurveClock
from curve_formation.core.formation.curves import Curve, Fit
from curve_formation.core.formation.motion import CurveMotion
from curve_formation.core.record.metrics import MAX_STAMP_GAP


def received_phases(experiment: Experiment,
                    curves: Sequence[tuple[float, int, Curve, ArrayLike, CurveClock | None]]
                    ) -> tuple[Phase, ...]:
    """The phases a run followed, from the curve messages it received, in order: curves is a
    list of (t, curve id, curve, s, clock) (see ReceivedPhases.add).
    """
    followed = ReceivedPhases(experiment)
    for when, curve_id, curve, given, clock in curves:
        followed.add(when, curve_id, curve, given, clock)
    return followed.phases


class ReceivedPhases:
    """The phases a run followed, folded from its curve messages one at a time (a run of hours
    receives a curve every second or faster: only the phases are kept, not the messages).
    """

    def __init__(self, experiment: Experiment) -> None:
        self.experiment = experiment
        self._phases: list[Phase] = []
        self._ids: list[int] = []

    @property
    def phases(self) -> tuple[Phase, ...]:
        return tuple(self._phases)

    def add(self, when: float, curve_id: int, curve: Curve, given: ArrayLike,
            clock: CurveClock | None = None) -> None:
        """One curve message received at `when` (s since the first curve) with its id, the
        agents' parameters s (n,) it carried and its clock (CurveClock on the same time scale
        as `when`, or None). The first message of an id starts a phase; a later one with the
        same id re-assigns its targets (Phase.changes) or, for a moving curve, only renews
        it. A curve equal to the schedule's curve of the same index (moved on as its clock
        says) keeps that phase's fit (residuals) and motion; any other (an observed curve) has
        no fit residual (NaN). A moving phase starts when its clock says it began to move
        (where that is within MAX_STAMP_GAP of the message's arrival); without a clock, from
        its first message on or from earlier, where its renewals show the first came late
        (_moving_since).
        """
        phases = self._phases
        s = np.asarray(given, dtype=float)
        dated = clock is not None and abs(clock.valid_at - when) <= MAX_STAMP_GAP
        if self._ids and curve_id == self._ids[-1]:
            last = phases[-1]
            if last.motion is not None:
                last = phases[-1] = (
                    dataclasses.replace(last, start=clock.motion_began)
                    if dated and clock is not None
                    else _moving_since(last, last.motion, when, curve))
            if not np.array_equal(s, last.changes[-1][1] if last.changes else last.s):
                phases[-1] = dataclasses.replace(   # targets on the curve as it started
                    last, changes=last.changes + ((float(when), s, last.curve.points(s)),))
            return
        k = len(phases)
        scheduled = self.experiment.phases[k] if k < len(self.experiment.phases) else None
        moved = 0.0 if clock is None or not dated else clock.moving_for
        expected = (None if scheduled is None else scheduled.curve if scheduled.motion is None
                    else scheduled.motion.curve(scheduled.curve, moved))
        same = scheduled is not None and expected is not None and expected.matches(curve)
        start = float(when)
        if same and scheduled is not None:
            fit, motion, curve = scheduled.fit, scheduled.motion, scheduled.curve
            if motion is not None and dated and clock is not None:
                start = clock.motion_began
        else:
            fit, motion = Fit(curve, math.nan, math.nan, 0), None
        phases.append(Phase(k, start, fit, s, curve.points(s), curve.basis.stacked(s),
                            motion=motion))
        self._ids.append(curve_id)


def _moving_since(phase: Phase, motion: CurveMotion, when: float, renewal: Curve) -> Phase:
    """A phase moving by `motion` started no later than a renewal received at `when`
    (s) tells: the renewal is the curve `elapsed` s into its motion, so the phase began at
    most `when - elapsed` (the earliest over the renewals: a message only arrives late). A
    reader that joined late gets the first message when the curve has already moved (as a
    latched message, 0.3 s late was seen), and would judge the robots against a curve left
    behind.
    """
    elapsed = motion.elapsed(phase.curve, renewal, when - phase.start)
    if elapsed is None or when - elapsed >= phase.start:
        return phase
    return dataclasses.replace(phase, start=when - elapsed)
