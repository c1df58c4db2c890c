"""The law's settings as a file gives them (Gains) and as one tick takes them (Law).

Units: gains k1 in 1/s, the offset l in m, rates in 1/s.
"""

import dataclasses
from dataclasses import dataclass
from typing import NamedTuple

from curve_formation.core.controller.settings import default, LAW_NAMES


# Disturbance estimators, by name in the experiment YAML (`controller.law`) and by code in the
# compiled simulator.
LAWS = {name: code for code, name in enumerate(LAW_NAMES)}
OBSERVER = LAWS['observer']


@dataclass(frozen=True)
class Gains:
    """The law and its gains.

    k1 (1/s) on the target error, k2 on the estimate, offset l (m) of the control point.
    law: 'paper' (dhat' = k2 R^T e), 'adaptive' (the same with per-channel gains
    `adaptation` = (gamma_v, gamma_w) multiplying each channel's rate) or 'observer' (dhat
    tracks the measured body velocity minus the command, over k2, at `observer_rate` (1/s)).
    sampled_heading: under a zero-order hold, turn as the continuous law would over one
    period (sampled_feedback) instead of holding its instantaneous turn rate.
    tail_radius (m; 0: off), tail_gain: the finite-time tail (tail_feedback).
    reverse: a robot may drive backwards, steering the point behind its axle
    (core.controller.driving), when that reaches its target sooner.
    observer_growth: law observer with the disturbance added on the PC: the largest factor
    of ray_growth's search along a saturated motion (1: off).
    observer_order: law observer: 2 also estimates how fast the disturbance changes
    (observer.observer_update); 1 the first-order observer.
    """

    k1: float
    k2: float
    offset: float
    law: str = default('controller.law')
    adaptation: tuple[float, float] = default('controller.adaptation')
    observer_rate: float = default('controller.observer_rate')
    sampled_heading: bool = default('controller.heading') == 'sampled'
    tail_radius: float = default('controller.tail.radius')
    tail_gain: float = default('controller.tail.gain')
    reverse: bool = default('controller.reverse')
    observer_growth: float = default('controller.observer_growth')
    observer_order: int = default('controller.observer_order')

    @property
    def law_code(self) -> int:
        return LAWS[self.law]

    def paper_law(self) -> 'Gains':
        """These gains with the paper's reference law (its estimator, its heading command)."""
        return dataclasses.replace(self, law='paper', sampled_heading=False)

    def hold_period(self, rate_hz: float | None) -> float:
        """The `period` argument of agent_input at this rate (Hz; None = continuous): the
        control period with the sampled heading under a zero-order hold, else 0.
        """
        return 1.0 / rate_hz if self.sampled_heading and rate_hz else 0.0

    def estimator_gains(self) -> tuple[float, float]:
        """(gamma_v, gamma_w): per-channel multipliers of the paper's estimator rate."""
        return self.adaptation if self.law == 'adaptive' else (1.0, 1.0)

    def tick_law(self, rate_hz: float | None, on_pc: bool = False) -> 'Law':
        """The Law of one control tick at rate_hz (None: continuous control)."""
        gamma_v, gamma_w = self.estimator_gains()
        return Law(self.law_code, self.k1, self.k2, self.offset, gamma_v, gamma_w,
                   self.hold_period(rate_hz), 1.0 / rate_hz if rate_hz else 0.0,
                   self.observer_rate, on_pc, self.tail_radius, self.tail_gain, self.reverse,
                   self.observer_growth, self.observer_order)


class Law(NamedTuple):
    """Gains as agent_command takes them (one argument, also inside the compiled simulator).

    code: LAWS; k1 (1/s), k2, offset l (m), per-channel estimator gains, hold: the period of
    the sampled heading (s; 0: the paper's heading), period: the control period (s; 0:
    continuous), observer_rate (1/s), on_pc: the disturbance is added on the PC,
    tail_radius (m), tail_gain: tail_feedback's, reverse: driving.drive_direction may
    choose to drive backwards, max_growth: ray_growth's largest factor (1: off), order: the
    observer's (1 or 2).
    """

    code: int
    k1: float
    k2: float
    offset: float
    gamma_v: float
    gamma_w: float
    hold: float
    period: float
    observer_rate: float
    on_pc: bool
    tail_radius: float
    tail_gain: float
    reverse: bool
    max_growth: float
    order: int
