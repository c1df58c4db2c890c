"""Monitor: samples every robot's pose, command and estimate, as the runner's observer.

t = 0 is when the first curve arrives. Rows are sampled at `record_hz` from the latest values
(core.record.sampling, as the analysis of the run's bag samples them; NaN until a value is seen); a
sample due while the process was held up is skipped (_sample).
Not a console script: the runner and tests create it in-process.
"""

from collections import deque
from collections.abc import Callable
import math
import time
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped, Twist, Vector3Stamped
import numpy as np
from rclpy.node import Node
from rclpy.subscription import Subscription
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from curve_formation import diagnostics
from curve_formation.core.config.agents import geofence
from curve_formation.core.config.experiment import Experiment, Phase
from curve_formation.core.controller.estop import stopped_intervals
from curve_formation.core.record.received_phases import ReceivedPhases
from curve_formation.core.record.sample_log import SampleLog
from curve_formation.core.record.sampling import LatestValues
from curve_formation.interface import robot_name
from curve_formation.nodes import messages, qos, topics
from curve_formation.nodes.command_source import (
    command_publishers,
    publisher_count,
    WATCH_PERIOD,
)
from curve_formation.nodes.readiness import subscribe_to_curve
from curve_formation.nodes.runtime import now_seconds, WithMessageInfo


TIMING_WINDOW = 3000   # newest command arrivals / tick latencies kept per robot
WAKE_LIMIT = 1.0       # s after a late timer call that samples wait at most for a fresh pose


def recording_fields(n: int, ground_truth: bool) -> dict[str, Any]:
    """The monitor's SampleLog fields for n robots: t (s since the first curve), poses (n, 3)
    (m, m, rad; world frame), commands (n, 2) (m/s, rad/s), dhat (n, 2), curve_id, unseen (n,)
    (robots missing from the poses), pose_stamps (n,) (s since t = 0: when each pose was
    taken) and, with ground_truth, true_poses (n, 3): the fake robots' own poses.
    """
    fields = {'t': ((), float), 'poses': ((n, 3), float), 'commands': ((n, 2), float),
              'dhat': ((n, 2), float), 'curve_id': ((), np.int64), 'unseen': ((n,), bool),
              'pose_stamps': ((n,), float)}
    if ground_truth:
        fields['true_poses'] = ((n, 3), float)
    return fields


class Monitor(Node):
    """Subscribes to all robots' topics and samples them into a SampleLog (`recording`).

    What it keeps does not grow with the run's length: samples go to disk (SampleLog), curve
    messages are folded into the phases they start (ReceivedPhases), e-stop states are kept
    where a holder's state changed, timing rows in windows of TIMING_WINDOW.
    """

    def __init__(self, n: int, record_hz: float = 20.0, ground_truth: bool = False,
                 watch: bool = True, adoption: bool = True,
                 experiment: Experiment | None = None, poses_from_all: bool = False,
                 **kwargs: Any) -> None:
        """ground_truth: also record the fake robots' true poses (when a camera tracks them).
        experiment: the run's (core.config.experiment.Experiment): the phases followed are told
        from
        its schedule (`followed`); without it, none are kept.
        watch False: only the curve (for t0), on a host of a split run that neither measures
        nor starts the curve server. adoption: also read every controller's state, to time
        when each robot takes up a new curve (`adopted`); states come at the pose rate (1500
        messages a second with 50 robots), so a run without a curve switch leaves it out.
        poses_from_all: the poses also come all together on /formation/robot_poses (a camera
        tracker, one fake arena): read there, one message a frame instead of n.
        """
        super().__init__('formation_monitor', start_parameter_services=False, **kwargs)
        self.n = n
        # Each robot's latest pose, command and estimate, sampled as the bag analysis samples
        # them; a pose is refused where the controllers would refuse it
        # (core.controller.plausibility).
        self.latest = LatestValues(n, None if experiment is None else geofence(experiment))
        self.true_poses = np.full((n, 3), np.nan) if ground_truth else None
        # per robot, its last two true poses [(stamp s, x, y, theta)]; over every tick that
        # drove, how far (m) the pose its law used was from the truth then: how many ticks,
        # the sum of squares (m^2)
        self.true_history: list[list[tuple[float, float, float, float]]] = [
            [] for _ in range(n)]
        self.law_pose_tally = [0, 0.0]
        self.command_times = np.full(n, np.nan)
        self.pose_received = np.full(n, np.nan)   # s, this node's clock, of the newest pose
        self.curve_id: int | None = None
        self.t0: float | None = None
        # curve id -> DDS source timestamp of its first message (s)
        self.curve_times: dict[int, float] = {}
        self.followed = None if experiment is None else ReceivedPhases(experiment)
        self.unseen = np.zeros(n, bool)   # robots missing from /formation/robot_poses now
        self.contacts = None       # fake_arena's contact summary, as last reported
        # robot_bridge name -> its reports [(t s, level, message, {key: value})]: the newest
        # and each that began a loss or an error (level 2 after a lower one)
        self.links: dict[str, list[tuple[float, int, str, dict[str, str]]]] = {}
        # robot name -> its controller's latest estimates of it (diagnostics.robot_estimates)
        self.estimates: dict[str, dict[str, object]] = {}
        self._link_onset_last: set[str] = set()   # links whose newest kept report began a loss
        # (received s, holder, engaged) where a holder's state changed
        self.estop_events: list[tuple[float, str, bool]] = []
        self._estop_held: dict[str, bool] = {}      # holder -> its state last heard
        # (t s since t = 0 or None, node key, how) reported here
        self.node_deaths: list[tuple[float | None, str, str]] = []
        # robot -> [[from s, to s or None, publishing nodes]] while its cmd_vel had several
        self.command_sources: dict[str, list[list[Any]]] = {}
        # Per robot, one (published, received, handled) row per command (s, system clock):
        # the DDS source timestamp, the time DDS received it here, the time this callback ran.
        self.command_arrivals: list[deque[tuple[float, float, float]]] = [
            deque(maxlen=TIMING_WINDOW) for _ in range(n)]
        # estimate arrival - pose stamp (s)
        self.tick_latencies: list[deque[float]] = [deque(maxlen=TIMING_WINDOW)
                                                   for _ in range(n)]
        # (robot, curve id) -> DDS source timestamp of its first state on that curve (s)
        self.adopted: dict[tuple[int, int], float] = {}
        self.recording = SampleLog(recording_fields(n, ground_truth))
        self.poses_from_all = poses_from_all
        self.command_readers: list[Subscription] = []   # robot i's cmd_vel at i - 1
        for i in range(1, n + 1 if watch else 1):
            if not poses_from_all:
                self._subscribe(topics.POSE, lambda m, i=i: self._on_pose(i, m), i)
            self.command_readers.append(self._subscribe(
                topics.CMD_VEL, WithMessageInfo(lambda m, info, i=i: self._on_cmd(i, m, info)),
                i))
            self._subscribe(topics.ESTIMATE, lambda m, i=i: self._on_estimate(i, m), i)
            if adoption:
                self._subscribe(topics.STATE, WithMessageInfo(
                    lambda m, info, i=i: self._on_state(i, m, info)), i)
            if ground_truth:
                self._subscribe(topics.TRUE_POSE, lambda m, i=i: self._on_true_pose(i, m), i)
                self._subscribe(topics.TICK, lambda m, i=i: self._on_tick(i, m), i)
        subscribe_to_curve(self, WithMessageInfo(self._on_curve), log=False,
                           event_callbacks=qos.observer_events())
        if watch:
            self._subscribe(topics.ROBOT_POSES, self._on_robot_poses)
            self._subscribe(topics.DIAGNOSTICS, self._on_diagnostics)
            self._subscribe(topics.ESTOP_STATE, self._on_estop_state)
            self.create_timer(WATCH_PERIOD, self._watch_command_sources)
            self.create_timer(1.0 / record_hz, self._sample)
        self.period = 1.0 / record_hz
        # time.monotonic() of the sampling timer's last call
        self.last_call: float | None = None
        self.late_samples = 0      # samples skipped after the timer came late (see _sample)
        self.closed = False        # the run is over (close): nothing more is sampled
        # time.monotonic() of a late call whose fresh pose is awaited
        self._woke_at: float | None = None
        self._pose_arrival = -np.inf   # time.monotonic() the newest pose message arrived

    def _subscribe(self, name: str, callback: Callable[..., Any], robot: int | str | None = None
                   ) -> Subscription:
        return topics.subscription(self, name, callback, robot,
                                   event_callbacks=qos.observer_events())

    def _on_pose(self, i: int, msg: PoseStamped) -> None:
        self._took_pose(i, *messages.pose_from_msg(msg), now_seconds(self))

    def _took_pose(self, i: int, x: float, y: float, theta: float, stamp: float,
                   received: float) -> None:
        """Robot i's (1-based) pose taken at `stamp`, received at `received` (s)."""
        self._pose_arrival = time.monotonic()
        self.pose_received[i - 1] = received
        self.latest.pose(i, x, y, theta, stamp)

    def _on_true_pose(self, i: int, msg: PoseStamped) -> None:
        x, y, theta, stamp = messages.pose_from_msg(msg)
        assert self.true_poses is not None   # subscribed with ground truth only
        self.true_poses[i - 1] = (x, y, theta)
        history = self.true_history[i - 1]
        history.append((stamp, x, y, theta))
        del history[:-2]

    def _on_tick(self, i: int, msg: JointState) -> None:
        """The pose robot i's law used at its tick against the truth then, extrapolated
        from the last two true poses (the fake robots and the controllers share this clock).
        """
        tick = messages.tick_from_msg(msg)
        history = self.true_history[i - 1]
        if self.t0 is None or len(history) < 2 or not math.isfinite(tick.get('x', math.nan)):
            return
        (t0, x0, y0, _), (t1, x1, y1, _) = history
        at = messages.stamp_to_seconds(msg.header.stamp)
        share = (at - t1) / (t1 - t0) if t1 > t0 else 0.0
        truth_x, truth_y = x1 + share * (x1 - x0), y1 + share * (y1 - y0)
        gap = math.hypot(tick['x'] - truth_x, tick['y'] - truth_y)
        self.law_pose_tally[0] += 1
        self.law_pose_tally[1] += gap * gap

    def law_pose_rms(self) -> float | None:
        """RMS (m) over every tick of every robot of how far the pose its law used was from
        the truth (None before any tick).
        """
        count, squares = self.law_pose_tally
        return math.sqrt(squares / count) if count else None

    def _on_cmd(self, i: int, msg: Twist, info: dict[str, Any]) -> None:
        self.latest.command(i, *messages.twist_from_msg(msg))
        self.command_times[i - 1] = now_seconds(self)
        self.command_arrivals[i - 1].append((info['source_timestamp'] * 1e-9,
                                             info['received_timestamp'] * 1e-9,
                                             time.time()))

    def _on_estimate(self, i: int, msg: Vector3Stamped) -> None:
        self.latest.estimate(i, msg.vector.x, msg.vector.y)
        if self.t0 is not None:
            self.tick_latencies[i - 1].append(
                now_seconds(self) - messages.stamp_to_seconds(msg.header.stamp))

    def _on_state(self, i: int, msg: JointState, info: dict[str, Any]) -> None:
        curve_id = messages.state_from_msg(msg)[2]
        self.adopted.setdefault((i, curve_id), info['source_timestamp'] * 1e-9)

    def _on_curve(self, msg: Float64MultiArray, info: dict[str, Any]) -> None:
        # Dated when received, as the recorder dates it in a bag (bags/analysis.py reads t = 0
        # from there): both run in the runner's process.
        curve, self.curve_id = messages.curve_from_msg(msg)
        now = now_seconds(self)
        self.curve_times.setdefault(self.curve_id, info['source_timestamp'] * 1e-9)
        if self.t0 is None:
            self.t0 = now
        given = messages.agent_parameters_from_msg(msg)
        # a curve without the agents' parameters tells nobody's target: no phase (the
        # analysis refuses a bag of one)
        if self.followed is not None and given is not None:
            clock = messages.curve_clock_from_msg(msg)
            self.followed.add(now - self.t0, self.curve_id, curve, given,
                              None if clock is None else clock.since(self.t0))

    def _watch_command_sources(self) -> None:
        if self.t0 is None:
            return
        t = now_seconds(self) - self.t0
        for i in range(1, self.n + 1):
            topic = topics.robot_topic(i, topics.CMD_VEL)
            episodes = self.command_sources.get(robot_name(i), [])
            open_ = bool(episodes) and episodes[-1][1] is None
            # named only past one publisher (a walk of the graph; the count is a number)
            if publisher_count(self, topic, self.command_readers[i - 1]) <= 1 and not open_:
                continue
            names = command_publishers(self, topic)
            if len(names) > 1 and not open_:
                self.command_sources.setdefault(robot_name(i), []).append([t, None, names])
            elif len(names) <= 1 and open_:
                episodes[-1][1] = t

    def _on_estop_state(self, msg: DiagnosticStatus) -> None:
        try:
            report = messages.estop_state_from_msg(msg)
        except messages.MessageError:
            return
        if self._estop_held.get(report.holder) != report.engaged:
            self._estop_held[report.holder] = report.engaged
            self.estop_events.append((now_seconds(self), report.holder, report.engaged))

    def command_times_since(self, since: float) -> dict[int, tuple[list[float], list[float]]]:
        """{robot: (published, received)} of its commands (one per control tick; s, system
        clock, DDS timestamps) published from `since` (s, system clock) on, the newest
        TIMING_WINDOW at most.
        """
        return {i + 1: ([sent for sent, _, _ in rows if sent >= since],
                        [got for sent, got, _ in rows if sent >= since])
                for i, rows in enumerate(self.command_arrivals)}

    @property
    def estop_engaged(self) -> bool:
        """Whether some e-stop holder holds the robots now, as last heard."""
        return any(self._estop_held.values())

    def estop_intervals(self, end: float) -> list[tuple[float, float | None]]:
        """[(start, stop or None)] (s since t = 0, up to `end`) while a node held the e-stop
        (core.controller.estop.stopped_intervals); [] before t = 0.
        """
        if self.t0 is None:
            return []
        return stopped_intervals([(t - self.t0, holder, engaged)
                                  for t, holder, engaged in self.estop_events], end)

    def close(self) -> None:
        """The run is over: sample no more. Its nodes are stopped next, and what they do
        while stopping (zero commands, robots left behind a moving curve) is not the run.
        """
        self.closed = True

    def report_death(self, key: str, how: str) -> tuple[float | None, DiagnosticArray]:
        """A node of the run died: kept (node_deaths). Returns (its t, s since t = 0 or None;
        the /diagnostics message that tells it, stamped now: diagnostics.NODE_DEATH_REPORTER).

        The message is not published: the runner writes it into its bag. A publisher of its
        own in this process was seen to hang in Fast DDS when destroyed at the run's end.
        """
        now = now_seconds(self)
        t = None if self.t0 is None else now - self.t0
        self.node_deaths.append((t, key, how))
        status = DiagnosticStatus(
            level=DiagnosticStatus.ERROR, name=self.get_fully_qualified_name(),
            hardware_id=diagnostics.NODE_DEATH_REPORTER, message=f'node {key} died: {how}',
            values=[KeyValue(key='node', value=key), KeyValue(key='how', value=how)])
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = messages.seconds_to_stamp(now)
        return t, msg

    def followed_phases(self) -> tuple[Phase, ...]:
        """The phases the run followed (core.config.experiment.ReceivedPhases); () without one."""
        return () if self.followed is None else self.followed.phases

    def _on_robot_poses(self, msg: JointState) -> None:
        try:
            poses, stamp = messages.robot_poses_from_msg(msg)
        except messages.MessageError:
            return
        if len(poses) != self.n:
            return
        self.unseen = ~np.isfinite(poses).all(axis=1)
        if self.poses_from_all:   # each seen robot's pose, as its own message would give it
            received = now_seconds(self)
            for i in np.flatnonzero(~self.unseen):
                x, y, theta = map(float, poses[i])
                self._took_pose(int(i) + 1, x, y, theta, stamp, received)

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.hardware_id == diagnostics.CONTACT_REPORTER:
                self.contacts = diagnostics.contacts_from_report(
                    {kv.key: kv.value for kv in status.values})
            elif status.name.endswith(diagnostics.CONTROLLER_REPORTER):
                self.estimates[status.hardware_id] = diagnostics.robot_estimates(
                    {kv.key: kv.value for kv in status.values})
            elif status.name.endswith(diagnostics.LINK_REPORTER) and self.t0 is not None:
                level = status.level[0] if isinstance(status.level, bytes) else status.level
                report = (messages.stamp_to_seconds(msg.header.stamp) - self.t0, int(level),
                          status.message, {kv.key: kv.value for kv in status.values})
                self._keep_link_report(status.name, report)

    def _keep_link_report(self, name: str, report: tuple[float, int, str, dict[str, str]]
                          ) -> None:
        """Keep a link's newest report and each that began a loss or an error (level 2
        after a lower level): link reports come every second for the whole run.
        """
        kept = self.links.setdefault(name, [])
        began = report[1] >= 2 and (not kept or kept[-1][1] < 2)
        if kept and name not in self._link_onset_last:
            kept.pop()
        kept.append(report)
        if began:
            self._link_onset_last.add(name)
        else:
            self._link_onset_last.discard(name)

    def ready(self) -> bool:
        """Every robot's pose and every controller's command has been seen."""
        return not self.missing()

    def missing(self) -> list[str]:
        """The inputs not heard yet: each robot's pose (its topic, or its row of
        /formation/robot_poses where the poses are read) and cmd_vel.
        """
        unposed = np.flatnonzero(np.isnan(self.latest.pose_stamps)) + 1
        return ([f'robot {i} on {topics.ROBOT_POSES}' if self.poses_from_all
                 else topics.robot_topic(int(i), topics.POSE) for i in unposed]
                + [topics.robot_topic(int(i) + 1, topics.CMD_VEL)
                   for i in np.flatnonzero(np.isnan(self.command_times))])

    def _sample(self) -> None:
        # A call more than half a period late means this process was held up (a stalled
        # machine, a garbage collection): the executor calls the timer before the messages
        # that queued meanwhile, and the publishers held up with it resume when the scheduler
        # lets them, so the poses held are as old as the delay (at 1 cm/s, a 0.33 s stall read
        # as a 3.3 mm error of every robot). Samples are skipped from that call until a pose
        # arrives after it (at most WAKE_LIMIT: a robot that went silent is still recorded);
        # a steadily late run thus still records every other sample.
        now, last = time.monotonic(), self.last_call
        self.last_call = now
        if self._woke_at is not None:
            if self._pose_arrival <= self._woke_at and now - self._woke_at < WAKE_LIMIT:
                self.late_samples += 1
                return
            self._woke_at = None
        elif last is not None and now - last > 1.5 * self.period:
            self._woke_at = now
            self.late_samples += 1
            return
        if self.t0 is None or self.closed:
            return
        row = self.latest.row(now_seconds(self), self.t0)
        row.update(curve_id=self.curve_id, unseen=self.unseen)
        if self.true_poses is not None:
            row['true_poses'] = self.true_poses
        self.recording.append(**row)
