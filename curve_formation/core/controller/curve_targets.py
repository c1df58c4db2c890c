"""Every agent's target on a curve a controller received, as it held when the curve came and
how it moves (a moving curve's target velocities): what a controller steers its own point to
and converts a neighbour's error on the curve before into.

Targets in the arena frame (m), velocities in m/s, times in s on the controller's clock.
"""

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from curve_formation.core.base.shapes import FloatArray, Point
from curve_formation.core.formation.assignment import AssignmentError, check_assumptions
from curve_formation.core.formation.curves import Curve


@dataclass(frozen=True)
class CurveTargets:
    """Every agent's target on one curve (n, 2; m, arena frame) as it held at `dated` (s, this
    controller's clock), their velocities (n, 2; m/s; zero on a still curve) and parameters.
    """

    curve_id: int
    targets: FloatArray
    velocities: FloatArray
    dated: float
    s: FloatArray   # every agent's curve parameter s_i (n,)
    curve: Curve    # the curve they lie on

    def at(self, j: int, t: float) -> Point:
        """Agent j's (1-based) target at t (s)."""
        age = max(t - self.dated, 0.0)
        tx, ty = self.targets[j - 1] + self.velocities[j - 1] * age
        return float(tx), float(ty)


def moving_share(aim: float, period: float, moves_from: float) -> float:
    """The part (0 to 1) of a command's period that a target moving from `moves_from` (s)
    moves in, the command acting from `aim` (s) for `period` s: all of it, except for a
    curve announced before it begins to move. What the feed-forward is scaled by.
    """
    return min(max((aim + period - moves_from) / period, 0.0), 1.0)


def curve_targets(curve: Curve, curve_id: int, s_all: Sequence[float] | FloatArray | None,
                  rate: Curve | None, agent_count: int, dated: float,
                  kept: CurveTargets | None = None) -> CurveTargets:
    """The targets G(s_i) xi of a curve received with every agent's parameter s_all (n,)
    and, for a moving curve, its coefficient rate (1/s), holding at `dated`. Raises
    AssignmentError (a ValueError) if s_all is missing, of another team's size, or breaks
    the paper's assumptions: agents never derive s_i themselves. kept: the targets held
    now; a still curve sent again (the same id, coefficients and s_i: the curve server
    renews its curve every second) keeps them, checked already (with 50 robots, five
    controllers a process redoing the check at once on every renewal delayed their ticks).
    """
    if (kept is not None and rate is None and kept.curve_id == int(curve_id)
            and not kept.velocities.any() and s_all is not None
            and np.array_equal(kept.s, np.asarray(s_all, dtype=float))
            and kept.curve.matches(curve, atol=0.0)):
        return replace(kept, dated=dated)
    if s_all is None:
        raise AssignmentError("the curve carries no agent parameters s_i (the curve "
                              "server's curves do)")
    if len(s_all) != agent_count:
        raise AssignmentError(f'the curve assigns {len(s_all)} agent parameters, this '
                              f'team has {agent_count} agents')
    s = np.array(s_all, dtype=float)
    check_assumptions(curve.basis, s)
    return CurveTargets(int(curve_id), curve.points(s),
                        np.zeros((agent_count, 2)) if rate is None else rate.points(s), dated,
                        s, curve)


def error_on(error: Point, j: int, old: CurveTargets, new: CurveTargets, taken: float
             ) -> Point:
    """Agent j's error sent on curve `old` as one on `new`: its point (error plus its old
    target) against its new target, both where they were at `taken`.
    """
    (ox, oy), (tx, ty) = old.at(j, taken), new.at(j, taken)
    return error[0] + ox - tx, error[1] + oy - ty
