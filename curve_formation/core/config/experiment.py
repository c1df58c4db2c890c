"""An experiment as the rest of the package uses it (Experiment: its phases, graph, gains,
limits, start) and the helpers that read it; config.loading builds one from a file.

Every problem is raised as :class:`ConfigError` naming the file, the key and what was expected.
"""

import dataclasses
from dataclasses import dataclass
import math
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from curve_formation.core.base.shapes import FloatArray
from curve_formation.core.config.schema import (
    ExperimentSpec,
    LimitsSpec,
    MONA_WHEEL_BASE,
    RobotsSpec,
)
from curve_formation.core.controller.disturbance import disturbance_at, Variation
from curve_formation.core.controller.gains import Gains
from curve_formation.core.controller.limits import WheelLimits
from curve_formation.core.controller.safety import Avoidance, AVOIDANCE_OFF
from curve_formation.core.formation.assignment import timed_order
from curve_formation.core.formation.curves import Curve, Fit
from curve_formation.core.formation.graph import DirectedGraph
from curve_formation.core.formation.motion import CurveMotion


# Poses a second (Hz) of each simulated robot without a camera (fake_arena, fake_robot and the
# tick pipeline): an overhead camera's.
DEFAULT_POSE_RATE = 30.0
# s a neighbour's state takes to arrive beyond waiting for the relaying robot's next pose
RELAY_DELIVERY = 0.01


# How long (s) before its start a curve that only begins to move where it is gets published
# (Experiment.announce_lead; the curve server's announce_ahead default).
ANNOUNCE_AHEAD = 0.2


@dataclass(frozen=True)
class Phase:
    """One curve of the schedule: active from `start` (s), fitted, with its agents' targets."""

    index: int
    start: float
    fit: Fit
    s: FloatArray        # (n,) agent parameters
    targets: FloatArray  # (n, 2) G(s_i) xi, arena frame (m)
    g_bar: FloatArray    # (2n, 2H)
    # Re-assignments while the phase was followed: ((t (s), s (n,), targets (n, 2)), ...)
    changes: tuple[tuple[float, FloatArray, FloatArray], ...] = ()
    motion: CurveMotion | None = None   # the curve moves from `start` on

    @property
    def curve(self) -> Curve:
        return self.fit.curve

    def curve_at(self, t: float) -> Curve:
        """The curve at time t (s, experiment time): moved, for a moving phase."""
        return self.curve if self.motion is None else self.motion.curve(self.curve,
                                                                         t - self.start)

    def assigned_from(self, points: FloatArray, speeds: FloatArray | None = None
                      ) -> 'Phase':
        """The phase with its targets permuted among the agents so that the agents headed for
        `points` (n, 2; arena frame, m) take the nearest of them (assignment.nearest_order;
        in time where their top `speeds` (n,; m/s) are given and that shortens the longest
        trip enough: assignment.timed_order): at a switch after the
        previous curve's targets were re-assigned, the agents are not where the assignment
        made at load time assumed, nor, their speeds known, as fast as it assumed.
        """
        order = timed_order(points, self.targets, speeds)
        if np.array_equal(order, np.arange(len(order))):
            return self
        s = self.s[order]
        return dataclasses.replace(self, s=s, targets=self.targets[order],
                                   g_bar=self.fit.curve.basis.stacked(s))


@dataclass(frozen=True)
class Experiment:
    """A checked experiment: graph, gains, limits, curve schedule, start poses."""

    spec: ExperimentSpec
    source: str
    graph: DirectedGraph
    gains: Gains
    limits: WheelLimits
    disturbance: FloatArray    # (n, 2) [d_v, d_w]
    initial_poses: FloatArray  # (n, 3)
    phases: tuple[Phase, ...]
    radius: float = 0.0        # bodies (m); 0: points
    avoidance: Avoidance = AVOIDANCE_OFF
    warnings: tuple[str, ...] = ()   # what `check` warns of: possible but questionable
    variations: tuple[Variation, ...] = ()   # the disturbance's changes over time

    def disturbance_at(self, t: ArrayLike) -> FloatArray:
        """(*t.shape, n, 2) the disturbance [d_v, d_w] at times t (s since the first curve)."""
        return disturbance_at(self.disturbance, self.variations, t)

    @property
    def n(self) -> int:
        return self.graph.n

    def tolerance(self, k: int = 0) -> float:
        """Phase k's settling tolerance (m): metrics.tolerance times its curve's size."""
        return self.spec.metrics.tolerance * self.phases[k].curve.size()

    @property
    def name(self) -> str:
        return self.spec.name

    def switched_to(self, phase: Phase, reassigned: bool, targets: FloatArray,
                    speeds: FloatArray | None = None) -> Phase:
        """The phase a scheduled switch starts: as assigned at load time, or, with `nearest`
        assignment, assigned again (Phase.assigned_from) from `targets` (n, 2; arena frame,
        m: the previous curve's targets as last sent, the robots' control points before the
        first curve) where the previous curve's targets were re-assigned on the way or the
        robots' top `speeds` (n,; m/s, assignment.top_speeds) are known. The curve server and
        the simulator both switch through here.
        """
        if self.spec.agents.assignment == 'nearest' and (reassigned or speeds is not None):
            return phase.assigned_from(targets, speeds)
        return phase

    def announce_lead(self, k: int, current: tuple[Curve, FloatArray] | None, moving: bool,
                      reassigned: bool, targets: FloatArray,
                      ahead: float = ANNOUNCE_AHEAD, speeds: FloatArray | None = None
                      ) -> float:
        """How long (s) before its start phase k is published: `ahead` if it only sets the
        current curve moving (its switched curve and s those of `current`, the (curve, s)
        last published, nothing moving now), so that every controller has it before it
        begins to move; else 0 (switched_to's speeds). The curve server and the nodes'
        pipeline both ask here.
        """
        phase = self.phases[k]
        if ahead <= 0 or phase.motion is None or current is None or moving:
            return 0.0
        switched = self.switched_to(phase, reassigned, targets, speeds)
        curve, s = current
        same = (curve.matches(switched.curve)
                and np.allclose(s, switched.s, rtol=0.0, atol=1e-9))
        return ahead if same else 0.0

    def report(self) -> dict[str, Any]:
        """What was checked, as a JSON-ready dict: graph, Theorem 1, Assumptions 1-2, fits."""
        cert = self.graph.certificate()
        return {
            'experiment': self.name, 'source': self.source, 'agents': self.n,
            'leader': self.graph.leader,
            'edges': [[e.source, e.target, e.weight] for e in self.graph.edges],
            'rooted_spanning_tree': True,
            'theorem1': {'P_diagonal': np.diag(cert.P).tolist(),
                         'min_eig_P': cert.min_eig_P, 'min_eig_Q': cert.min_eig_Q},
            'slowest_mode_of_L_plus_B': float(np.linalg.eigvals(
                self.graph.feedback_matrix).real.min()),
            'gains': {'law': self.gains.law, 'k1': self.gains.k1, 'k2': self.gains.k2,
                      'offset': self.gains.offset},
            'curves': [{'start': p.start, 'basis': p.curve.basis.describe(),
                        'fit_rms_residual': p.fit.rms_residual,
                        'fit_max_residual': p.fit.max_residual, 'samples': p.fit.samples,
                        # full, as checked at load (assignment.check_assumptions)
                        'size': p.curve.size(), 'rank_G_bar': min(2 * self.n,
                                                                  2 * p.curve.basis.H),
                        'n_le_H': self.n <= p.curve.basis.H,
                        's': p.s.tolist()} for p in self.phases],
            'bodies': {'radius': self.radius, 'avoidance': self.avoidance.on,
                       'margin': self.avoidance.margin if self.avoidance.on else None},
            'warnings': list(self.warnings),
        }


# What a simulation may ask for: fine steps (compute time), and recorded values (memory:
# samples x agents; 7 float64 each, so 1.8e7 is 1 GB).
MAX_STEPS = 100_000_000


MAX_RECORDED = 18_000_000


def phase_index(starts: ArrayLike, t: ArrayLike) -> np.ndarray:
    """The phase followed at each time t (R,) s: the index of the last phase begun by then,
    from the phases' start times `starts` (s, ascending, on t's clock); 0 before the first.
    The one rule of the simulators, the live run and the analysis of its bag.
    """
    starts = np.asarray(starts, dtype=float)
    return np.clip(np.searchsorted(starts, t, side='right') - 1, 0, max(len(starts) - 1, 0))


def whole_steps(interval: float, dt: float, what: str) -> int:
    """interval (s) as a whole number (>= 1) of steps dt (s); ValueError naming `what`."""
    steps = interval / dt
    if not math.isfinite(steps) or abs(steps - round(steps)) > 1e-6 * max(1.0, steps) \
            or round(steps) < 1:
        raise ValueError(f'{what} ({interval:g} s) must be a whole multiple of dt ({dt:g} s)')
    return int(round(steps))


# Control rate (Hz) of the ROS controllers when the experiment gives none (continuous).


def pose_rate(experiment: Experiment) -> float:
    """Poses a second (Hz) of each robot: the camera's rate, else a fake arena's or robot's
    (DEFAULT_POSE_RATE).
    """
    camera = experiment.spec.camera
    return float(camera.rate_hz) if camera is not None else DEFAULT_POSE_RATE


def wheel_radius(experiment: Experiment) -> float:
    """The wheel radius (m): limits.wheel_radius, or the schema's default without limits."""
    limits = experiment.spec.limits
    return float(limits.wheel_radius if limits is not None
                 else LimitsSpec.model_fields['wheel_radius'].default)


def wheel_base(experiment: Experiment) -> float:
    """Distance between the wheels (m): limits.wheel_base, or a Mona's without limits."""
    return float(experiment.limits.wheel_base or MONA_WHEEL_BASE)


def beside_experiment(experiment: Experiment, value: str | None) -> Path | None:
    """A file an experiment key names: as given when absolute, else relative to the file."""
    if not value:
        return None
    path = Path(value)
    return path if path.is_absolute() else Path(experiment.source).parent / path


def point_robots(experiment: Experiment) -> Experiment:
    """The experiment with the formation law alone, as the paper has it: robots are points
    that pass through each other (no bodies), no safety filter, no re-assignment, no online
    estimate of the link's latency or the motors' lag.
    """
    spec = experiment.spec
    agents = spec.agents.model_copy(update={'reassign_every': None})
    controller = spec.controller.model_copy(update={'estimate_latency': False,
                                                    'estimate_motors': False,
                                                    'motor_check': False})
    spec = spec.model_copy(update={'agents': agents, 'avoidance': None,
                                   'robots': RobotsSpec(), 'controller': controller})
    return dataclasses.replace(experiment, spec=spec, radius=0.0, avoidance=AVOIDANCE_OFF,
                               warnings=())
