"""The observer law's memory between a controller's ticks: which motion it measures (from
the pose of the last command's tick, or a later one that answers the current estimate),
what was commanded over it (the command acting, or what the commands realised through a
latency and the motors' lag), and the estimate a command uses (carried ahead at its rate,
second order). The update itself is observer.observer_update.

The memory is a plain float array (MEMORY fields) beside the command log
(core.controller.command_log) and the recent poses (POSE_FIELDS rows): the functions here
are what the nodes' MotionObserver and the batch simulator's kernel both call, plain scalar
math that numba compiles as it is.

Poses in the arena frame (m, rad); times in s on the controller's clock; commands in m/s and
rad/s.
"""

import math

import numpy as np

from curve_formation.core.base.shapes import Command, FloatArray, Pose
from curve_formation.core.controller.agent_config import AgentConfig
from curve_formation.core.controller.command_log import (
    DRIVEN,
    ESTIMATE,
    LIMITED,
    log_acting,
    log_append,
    log_first_acting_after,
    log_realised,
    make_room,
    Realised,
    REF_V,
    REF_W,
    SHIFT_V,
    SHIFT_W,
)
from curve_formation.core.controller.commands_sent import CommandsSent
from curve_formation.core.controller.gains import Law
from curve_formation.core.controller.inputs import MAX_PREDICTION
from curve_formation.core.controller.limits import WheelLimits
from curve_formation.core.controller.observer import carried_estimate, observer_update
from curve_formation.core.formation.dynamics import (
    body_from_wheels,
    measured_velocity,
    wheel_speeds,
)


# The poses an observer keeps to begin a motion at (a second at 30 Hz), and the shortest
# motion (s) it measures from a later start than the last tick's pose.
RECENT_POSES = 32
MIN_OBSERVED = 0.05
# A recent pose's row: its stamp, when taken on the controller's clock, the pose.
STAMP, TAKEN, X, Y, THETA = range(5)
POSE_FIELDS = 5
# The memory's fields: the pose (x, y, theta) and stamp of the previous command's tick, that
# tick's time and 1 while it holds (0: none since the robot last stopped); the last
# command's reference where the disturbance enters (before a PC-injected disturbance, else as
# sent), what the safety filter changed, 1 where the wheel limits cut it, 1 where its wheels
# were all within the dead band (idle motors); observer.ray_growth's state (factor, last
# right, last left wheel speed m/s); observer_order 2: the estimate's rate (per s) and the
# updates since the wheel limits last cut a command; the updates so far, when the last one's
# motion ended (NaN: none since the robot last stopped) and when the estimate's disturbance
# held (the middle of the motion it was learnt from).
(ANCHOR_X, ANCHOR_Y, ANCHOR_THETA, ANCHOR_STAMP, TICKED, ANCHORED, MEMORY_REF_V,
 MEMORY_REF_W, MEMORY_SHIFT_V, MEMORY_SHIFT_W, MEMORY_LIMITED, IDLE, GROWTH, LAST_RIGHT,
 LAST_LEFT, RATE_V, RATE_W, TRACKING, UPDATES, OBSERVED_UNTIL, ESTIMATED_AT) = range(21)
MEMORY = 21
NOT_REALISED: Realised = (False, 0.0, 0.0, 0.0, 0.0, False, False, 0)


def fresh_memory() -> FloatArray:
    """An observer's memory before any command (MEMORY,)."""
    memory = np.zeros(MEMORY)
    memory[GROWTH] = 1.0
    memory[OBSERVED_UNTIL] = math.nan
    return memory


def pose_append(poses: FloatArray, count: int, stamp: float, taken: float, x: float,
                y: float, theta: float) -> int:
    """Keep a pose stamped `stamp`, taken at `taken` (the oldest dropped when full); returns
    the new count.
    """
    count = make_room(poses, count)
    poses[count, STAMP], poses[count, TAKEN] = stamp, taken
    poses[count, X], poses[count, Y], poses[count, THETA] = x, y, theta
    return count + 1


def observer_stopped(memory: FloatArray) -> None:
    """The robot was stopped: nothing is learnt from the time it stands."""
    memory[ANCHORED] = 0.0
    memory[OBSERVED_UNTIL] = math.nan
    memory[MEMORY_REF_V:MEMORY_LIMITED + 1] = 0.0
    memory[GROWTH], memory[LAST_RIGHT], memory[LAST_LEFT] = 1.0, 0.0, 0.0


def dead_band_reference(v: float, w: float, ref_v: float, ref_w: float,
                        min_wheel_speed: float, wheel_base: float
                        ) -> tuple[float, float, bool]:
    """The observer's reference for the command (v, w) sent, and whether its motors idle:
    with a dead band (min_wheel_speed, m/s), less what the wheels commanded below it will not
    do, so that a robot standing still under a command too small to move it is not taken for
    a disturbance holding it back. Both wheels in the band: the motors are idle (nothing is
    learnt from that period, as when stopped).
    """
    if min_wheel_speed <= 0.0 or wheel_base <= 0.0:
        return ref_v, ref_w, False
    left, right = wheel_speeds(v, w, wheel_base)
    still_right = abs(right) < min_wheel_speed
    still_left = abs(left) < min_wheel_speed
    moved_v, moved_w = body_from_wheels(0.0 if still_left else left,
                                        0.0 if still_right else right, wheel_base)
    return ref_v + moved_v - v, ref_w + moved_w - w, still_right and still_left


def observer_commanded(memory: FloatArray, v: float, w: float, ref_v: float, ref_w: float,
                       shift_v: float, shift_w: float, limited: bool, x: float, y: float,
                       theta: float, stamp: float, now: float, min_wheel_speed: float,
                       wheel_base: float) -> None:
    """The command (v, w) sent at `now` from the pose (x, y, theta) stamped `stamp`, with
    agent_command's reference, shift and limited.
    """
    memory[ANCHOR_X], memory[ANCHOR_Y], memory[ANCHOR_THETA] = x, y, theta
    memory[ANCHOR_STAMP], memory[TICKED], memory[ANCHORED] = stamp, now, 1.0
    ref_v, ref_w, idle = dead_band_reference(v, w, ref_v, ref_w, min_wheel_speed, wheel_base)
    memory[MEMORY_REF_V], memory[MEMORY_REF_W] = ref_v, ref_w
    memory[MEMORY_SHIFT_V], memory[MEMORY_SHIFT_W] = shift_v, shift_w
    memory[MEMORY_LIMITED] = 1.0 if limited else 0.0
    memory[IDLE] = 1.0 if idle else 0.0


def log_sent(memory: FloatArray, log: FloatArray, count: int, at: float, v: float, w: float,
             stopped: bool) -> int:
    """Log the command (v, w) sent at `at` (stopped: a stop, motors off) with what the
    memory holds of it: its reference and shift, whether the limits cut it, driven unless
    stopped or idle in the dead band, and the updates made before it. Returns the log's new
    count (command_log.log_append).
    """
    return log_append(log, count, at, v, w, memory[MEMORY_REF_V], memory[MEMORY_REF_W],
                      memory[MEMORY_SHIFT_V], memory[MEMORY_SHIFT_W],
                      memory[MEMORY_LIMITED] != 0.0, not stopped and memory[IDLE] == 0.0,
                      int(memory[UPDATES]))


def estimate_used(memory: FloatArray, dhat_v: float, dhat_w: float, now: float,
                  latency: float, period: float, law: Law) -> Command:
    """The estimate a command sent at `now` compensates: carried from the middle of the
    motion it was learnt from (a pose's age counts) to the middle of the period the command
    holds for, once it acts (observer.carried_estimate).
    """
    ahead_by = min(max(now + latency + period / 2.0 - memory[ESTIMATED_AT], 0.0),
                   period + latency + MAX_PREDICTION)
    return carried_estimate(dhat_v, dhat_w, memory[RATE_V], memory[RATE_W],
                            int(memory[TRACKING]), ahead_by, law)


def _acting_over(log: FloatArray, count: int, latency: float, tau: float, elapsed: float,
                 ended: float, ticked: float, waits: bool, updates: int) -> Realised:
    """What was commanded over the motion of `elapsed` s ending at `ended` that the
    observer measures at the tick after `ticked`.
    """
    # A motion that began before the last tick (its first pose older than that tick) was
    # partly made under the command before: the commands are weighed by how long each
    # acted in it, and whether the limits cut is the last tick's command's, as when the
    # motion is wholly its own (the search along its ray is that command's).
    if tau > 0.0 or waits:
        return log_realised(log, count, ended, elapsed, latency, tau, updates)
    last = log_acting(log, count, ticked, latency)
    if ended - elapsed < ticked - 1e-9:   # mixed
        found, ref_v, ref_w, shift_v, shift_w, limited, driven, estimate = log_realised(
            log, count, ended, elapsed, latency, tau, updates)
        if found and last >= 0:
            limited = log[last, LIMITED] != 0.0
        return found, ref_v, ref_w, shift_v, shift_w, limited, driven, estimate
    if last < 0:
        return NOT_REALISED
    return (True, log[last, REF_V], log[last, REF_W], log[last, SHIFT_V], log[last, SHIFT_W],
            log[last, LIMITED] != 0.0, log[last, DRIVEN] != 0.0, int(log[last, ESTIMATE]))


def _answering_start(poses: FloatArray, pose_count: int, log: FloatArray, count: int,
                     updates: int, latency: float, begins: float, ends: float) -> int:
    """The row of a later start for a motion from `begins` to `ends` that began before the
    first command sent after the last update acted: the first pose taken from then on, at
    least MIN_OBSERVED before the end; -1 if the motion needs none or no such pose is held.
    """
    answering = log_first_acting_after(log, count, updates, latency)
    if math.isnan(answering) or begins >= answering - 1e-9:
        return -1
    for k in range(pose_count):
        if poses[k, TAKEN] >= answering - 1e-9:
            return k if poses[k, TAKEN] <= ends - MIN_OBSERVED else -1
    return -1


def observe_motion(memory: FloatArray, dhat_v: float, dhat_w: float, poses: FloatArray,
                   pose_count: int, log: FloatArray, count: int, x: float, y: float,
                   theta: float, stamp: float, ended: float, latency: float, tau: float,
                   law: Law, limits: WheelLimits) -> tuple[float, float]:
    """The estimate moved towards (motion measured since the last tick - command) / k2.

    (x, y, theta): the robot's latest pose, stamped `stamp`, taken at `ended`; poses: the
    recent ones; log: the commands sent; latency and tau (s): the commands' latency and the
    motors' lag, as told or estimated. The motion is the constant (v, w) that carries the
    previous tick's pose to it over the difference of their stamps; the command is the one
    sent at the previous tick, or with a command latency, a motor time constant or a motion
    that began before the previous tick (a pose older than the time between poses) what the
    commands realised over that motion; nothing is learnt while the motors were off. With a
    command latency, or a pose taken before the previous tick (a camera's frame older than a
    period), the observer waits for a motion made wholly under commands sent after its last
    update (their ESTIMATE), and blends over the time since that update: no delay enters
    the estimate's loop (docs/control-laws.md). Without a newer pose nothing is updated.
    Returns the estimate (dhat_v, dhat_w); the memory is updated in place.
    """
    if memory[ANCHORED] == 0.0:
        return dhat_v, dhat_w
    x0, y0, theta0 = memory[ANCHOR_X], memory[ANCHOR_Y], memory[ANCHOR_THETA]
    elapsed = stamp - memory[ANCHOR_STAMP]
    if elapsed <= 0.0:
        return dhat_v, dhat_w
    ticked, updates = memory[TICKED], int(memory[UPDATES])
    # A pose taken before the last tick cannot show that tick's command: waiting for one
    # that can keeps the pose's age out of the estimate's loop as it keeps the latency.
    waits = latency > 0.0 or ended < ticked
    acting = _acting_over(log, count, latency, tau, elapsed, ended, ticked, waits, updates)
    if not acting[0] or not acting[6]:
        return dhat_v, dhat_w
    if waits and acting[7] < updates:
        # the motion does not answer the current estimate yet: its part from the first
        # pose that can, if one is held
        later = _answering_start(poses, pose_count, log, count, updates, latency,
                                 ended - elapsed, ended)
        if later < 0:
            return dhat_v, dhat_w
        x0, y0, theta0 = poses[later, X], poses[later, Y], poses[later, THETA]
        elapsed = stamp - poses[later, STAMP]
        acting = _acting_over(log, count, latency, tau, elapsed, ended, ticked, waits,
                              updates)
        if not acting[0] or not acting[6] or acting[7] < updates:
            return dhat_v, dhat_w
    measured_v, measured_w = measured_velocity(x0, y0, theta0, x, y, theta, elapsed)
    memory[ESTIMATED_AT] = ended - elapsed / 2.0
    if waits and not math.isnan(memory[OBSERVED_UNTIL]):   # blended over the time since
        elapsed = max(elapsed, ended - memory[OBSERVED_UNTIL])   # the last update
    memory[OBSERVED_UNTIL] = ended
    (dhat_v, dhat_w, memory[RATE_V], memory[RATE_W], memory[GROWTH], memory[LAST_RIGHT],
     memory[LAST_LEFT], tracking) = observer_update(
        dhat_v, dhat_w, memory[RATE_V], memory[RATE_W], memory[GROWTH], memory[LAST_RIGHT],
        memory[LAST_LEFT], int(memory[TRACKING]), measured_v, measured_w, acting[1],
        acting[2], acting[3], acting[4], acting[5], law, limits, elapsed)
    memory[TRACKING] = tracking
    memory[UPDATES] += 1.0
    return dhat_v, dhat_w


class MotionObserver:
    """One controller's observer state (the functions above over its arrays); `updates`
    counts its updates so far.
    """

    def __init__(self, config: AgentConfig) -> None:
        self.config = config
        self.memory = fresh_memory()
        self.poses: FloatArray = np.zeros((RECENT_POSES, POSE_FIELDS))
        self.pose_count = 0

    @property
    def updates(self) -> int:
        return int(self.memory[UPDATES])

    def pose_seen(self, stamp: float, taken: float, pose: Pose) -> None:
        """A pose of the robot stamped `stamp`, taken at `taken` (the controller's clock)."""
        self.pose_count = pose_append(self.poses, self.pose_count, stamp, taken, *pose)

    def commanded(self, v: float, w: float, reference: Command, shift: Command,
                  limited: bool, measured: Pose, stamp: float, now: float,
                  min_wheel_speed: float) -> None:
        """The command (v, w) sent at `now` from the pose `measured` stamped `stamp`, with
        agent_command's reference, shift and limited (observer_commanded); min_wheel_speed
        (m/s): the motors' dead band, as told or estimated (0: none).
        """
        observer_commanded(self.memory, v, w, *reference, *shift, limited, *measured, stamp,
                           now, min_wheel_speed, self.config.limits.wheel_base)

    def stopped(self) -> None:
        """The robot was stopped: nothing is learnt from the time it stands."""
        observer_stopped(self.memory)

    def log_sent(self, sent: CommandsSent, at: float, v: float, w: float,
                 stopped: bool) -> None:
        """Log the command (v, w) sent at `at` in `sent` (stopped: a stop; log_sent)."""
        sent.count = log_sent(self.memory, sent.rows, sent.count, at, v, w, stopped)

    def estimate_used(self, dhat: list[float], now: float, latency: float,
                      period: float) -> Command:
        """The estimate a command sent at `now` compensates (estimate_used)."""
        return estimate_used(self.memory, dhat[0], dhat[1], now, latency, period,
                             self.config.law)

    def update(self, dhat: list[float], pose: Pose, stamp: float, ended: float,
               sent: CommandsSent, latency: float, tau: float) -> None:
        """Move dhat (in place) as observe_motion does, from the pose stamped `stamp` and
        taken at `ended`.
        """
        dhat[:] = observe_motion(self.memory, dhat[0], dhat[1], self.poses, self.pose_count,
                                 sent.rows, sent.count, *pose, stamp, ended, latency, tau,
                                 self.config.law, self.config.limits)
