"""A disturbance that changes over time: each agent's value d_i = [d_v, d_w] (m/s, rad/s)
times 1 + the sum of the variations acting on it at t (s since the first curve).

A variation is a sine (relative amplitude, period, phase), a step (a relative change from a
time on) or a ramp (a relative change reached linearly between two times, then held); each
acts on some agents or all (experiment key `disturbance.varies`).
"""

from dataclasses import dataclass
import math
from typing import Any, Literal, Sequence

import numpy as np
from numpy.typing import ArrayLike

from curve_formation.core.base.shapes import FloatArray


@dataclass(frozen=True)
class Variation:
    """One relative change over time; agents: 0-based indices it acts on (empty: all)."""

    kind: Literal['sine', 'step', 'ramp']
    amplitude: float = 0.0   # sine: relative amplitude
    period: float = 1.0      # sine: s
    phase: float = 0.0       # sine: rad at t = 0
    at: float = 0.0          # step: s
    start: float = 0.0       # ramp: s
    end: float = 1.0         # ramp: s
    change: float = 0.0      # step, ramp: relative change
    agents: tuple[int, ...] = ()

    def relative(self, t: ArrayLike) -> FloatArray:
        """The relative change at times t (s), shaped as t."""
        t = np.asarray(t, float)
        if self.kind == 'sine':
            return self.amplitude * np.sin(2.0 * math.pi * t / self.period + self.phase)
        if self.kind == 'step':
            return np.where(t >= self.at, self.change, 0.0)
        return self.change * np.clip((t - self.start) / (self.end - self.start), 0.0, 1.0)


def factors(variations: Sequence[Variation], n: int, t: ArrayLike) -> FloatArray:
    """(*t.shape, n) each agent's factor 1 + the sum of its variations at times t (s)."""
    t = np.asarray(t, float)
    out = np.ones(t.shape + (n,))
    for variation in variations:
        change = variation.relative(t)[..., None]
        if variation.agents:
            out[..., list(variation.agents)] += change
        else:
            out += change
    return out


def disturbance_at(base: FloatArray, variations: Sequence[Variation], t: ArrayLike
                   ) -> FloatArray:
    """(*t.shape, n, 2) the disturbance of agents whose constant values are base (n, 2) at
    times t (s).
    """
    base = np.asarray(base, float)
    return factors(variations, len(base), t)[..., None] * base


def varied(base: Sequence[float], variations: Sequence[Variation], i: int, t: float
           ) -> tuple[float, float]:
    """Agent i's (0-based) disturbance [d_v, d_w] at t (s): its constant value base times 1 +
    the sum of its variations then (what one node, knowing only its own agent, applies).
    """
    factor = 1.0 + sum(float(v.relative(t)) for v in variations
                       if not v.agents or i in v.agents)
    return base[0] * factor, base[1] * factor


class RunTime:
    """The run's time (s since its first curve) on a node's clock, from the curve messages'
    clocks (CurveClock.run_start: the curve server's clock, which this node's must follow, as
    chrony keeps a lab's hosts; a message without a run time dates it by its arrival).
    """

    def __init__(self) -> None:
        self.start: float | None = None   # the run's t = 0 on this node's clock (s)

    def heard(self, clock: Any, received: float) -> None:
        """A curve message with `clock` (CurveClock or None) arrived at `received` (s)."""
        if clock is not None and clock.run_start is not None:
            self.start = clock.run_start
        elif self.start is None:
            self.start = received

    def at(self, now: float) -> float | None:
        """The run's time at `now` (s, this node's clock); None before any curve."""
        return None if self.start is None else now - self.start
