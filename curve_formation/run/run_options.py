"""What a run of an experiment's node graph is asked to do, beyond the experiment file."""

from dataclasses import dataclass
import math
import os
from pathlib import Path

from curve_formation import scheduling
from curve_formation.bags.bag import DEFAULT_STORAGE


@dataclass(frozen=True)
class RunOptions:
    """Options of `curve-formation run` (runner.Run), all keyword, each with its default.

    single_process: every node in the runner's own executor instead of a process each.
    with_robots: start simulated robots (fake_robot or fake_arena); False for real ones.
    rate_hz: control rate (Hz; None: the experiment's).
    record_hz: the monitor's sampling rate (Hz).
    pose_noise: (position m, heading rad) standard deviations added to simulated poses.
    command_latency: delay (s) of every command at the simulated robots; command_jitter: how
        much each command's delay varies either way (s, uniform).
    faults: faults of the simulated robots, {'pose_drop': p (each pose lost with that
        probability), 'link_down': [robot, from s, for s] (fake_arena's link to a robot cut,
        from its first command that turns a wheel), 'silent': [robots] (links that never answer),
        'runaway': [robots] (answering, driving on whatever they are told), 'hidden':
        [robots] (fake_arena publishes no pose of them)}.
    node_variants: {package node module: module run in its place with the same parameters},
        e.g. a lab's own variant of formation_controller; the module defines NODE_CLASS.
    camera: None, or fake_camera parameter overrides ({} for none): poses then come from
        camera_tracker, fed by fake_camera (with_robots) or a real camera on /camera/image_raw.
    bridge: None, 'udp' or 'pty': each cmd_vel goes through a robot_bridge to fake_arena's
        emulated robots.
    bag_path: record a ROS 2 bag there (refused if it exists); bag_images: with camera frames;
        bag_storage: 'mcap' or 'sqlite3'.
    discovery_server: HOST:PORT of a Fast DDS discovery server to discover through.
    only: None (the whole graph here), or the PARTS this host runs of a graph split over
        several hosts on one ROS_DOMAIN_ID: each host starts its share, the one with
        'observer' measures the run.
    agents: None (every agent), or the agents (1-based) whose own nodes (controller, robot
        bridge, simulated robot) this host runs: a team's controllers spread over hosts.
    physics: the simulated robots' world, 'kinematic' or 'mujoco' (None: the experiment's
        physics.engine).
    isolated: a private random ROS_DOMAIN_ID and LOCALHOST discovery (tests, the demo);
        otherwise the caller's ROS_DOMAIN_ID (0 when unset) and discovery range, where the
        lab's RViz, `ros2 topic echo` and robot drivers are.
    animate: also write animation.mp4 of the run beside its figures (figures.animation).
    controllers_per_process: controllers sharing one process (one context and executor, as a
        component container; nodes.node_group); None: group_size's choice from the team.
    realtime_priority: SCHED_FIFO priority (1-99) of the controllers' processes (their
        `realtime_priority` parameter), so that a busy PC cannot delay their ticks; 0 = normal
        scheduling; without the permission they note it and run at normal scheduling. Not for
        a single-process run (the runner's own process).
    preflight: check every robot behind a link before the formation starts (run.preflight;
        runs with robot bridges only). allow_missing: robots (1-based) that may fail it: the
        run then goes on without them (the team renumbered, core.config.team).
    """

    single_process: bool = False
    with_robots: bool = True
    rate_hz: float | None = None
    record_hz: float = 20.0
    pose_noise: tuple[float, float] = (0.0, 0.0)
    command_latency: float = 0.0
    command_jitter: float = 0.0
    faults: dict | None = None
    node_variants: dict[str, str] | None = None
    camera: dict | None = None
    bridge: str | None = None
    bag_path: Path | str | None = None
    bag_images: bool = False
    bag_storage: str = DEFAULT_STORAGE
    discovery_server: str | None = None
    only: frozenset[str] | None = None
    agents: frozenset[int] | None = None
    isolated: bool = False
    physics: str | None = None
    animate: bool = False
    controllers_per_process: int | None = None
    realtime_priority: int = scheduling.CONTROLLERS
    preflight: bool = True
    allow_missing: frozenset[int] = frozenset()

    def runs(self, part: str) -> bool:
        """Whether this host runs `part` (one of PARTS)."""
        return self.only is None or part in self.only

    def group_size(self, n: int, cores: int | None = None) -> int:
        """Controllers per process for a team of n: as asked, else one group per core of
        this PC (`cores`; None: those this process may use; one controller each where the
        team has no more robots than cores), at most GROUP_MOST controllers each and at most
        MOST_GROUPS groups (with the curve server, the robots and the runner, 16 DDS
        participants). 1 in a single-process run (every node shares it anyway).
        """
        if self.single_process:
            return 1
        if self.controllers_per_process is not None:
            return self.controllers_per_process
        cores = cores or (len(os.sched_getaffinity(0)) if hasattr(os, 'sched_getaffinity')
                          else os.cpu_count() or 1)
        return max(math.ceil(n / MOST_GROUPS), min(GROUP_MOST, math.ceil(n / cores)))

    def runs_agent(self, agent: int | None) -> bool:
        """Whether this host runs the nodes of `agent` (None: a node of the whole team)."""
        return agent is None or self.agents is None or agent in self.agents


# The parts of a node graph one host can run (`run --only`): the curve server; the
# controllers; the robots (simulated: fake_robot or fake_arena; and the robot bridges, on the
# PC the robots' radios hang off);
# the camera nodes (camera_tracker, fake_camera); the observer (monitor, recorder, metrics).
# The faults of RunOptions.faults that name robots (fake_arena's fault_<name>): silent,
# runaway and hidden.
ROBOT_FAULTS = ('silent', 'runaway', 'hidden')
# The largest team whose simulated robots each run a fake_robot process of their own (past
# it, they share one fake_arena: a process per robot costs a DDS participant and a Python
# interpreter each).
SOLO_TEAM = 12
# The controllers: one group per core, each at most GROUP_MOST controllers (a crash takes
# down no more than these), at most MOST_GROUPS groups. Every process pays its own start
# (rclpy, numba: ~1 s of a core) and its own copy of every message it reads, and a message
# between processes costs ~0.1 ms of a core per reader where one within a process costs a
# few us. Measured on 2 cores (docs/performance.md): 9 robots' controllers and fake robots
# take 2.1-3.0 % of a core per robot in 1 or 2 groups, 5.9-6.0 % one process each;
# 50 robots in 2 processes of 25 hold 10 Hz with p99 jitter 13-14 ms and take 2.2 % of a
# core each, first curve at 5.2 s; in 10 processes of 5, 22-24 ms, 2.9 % and 9-11 s; 100 in
# 4 processes of 25 hold 9.7 Hz, in 12 of 9 they fell to 2.8 Hz.
GROUP_MOST = 25
MOST_GROUPS = 13
PARTS = ('curve_server', 'controllers', 'robots', 'camera', 'observer')

DEFAULTS = RunOptions()
