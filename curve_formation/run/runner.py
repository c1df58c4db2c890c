"""`curve-formation run`: one experiment YAML -> a ROS 2 node graph, run, measured.

Writes one parameters file per node into OUT/params/ (launches.py), starts every node as its
own process or all in one executor (node_graph.py), waits until every robot's pose and every
controller's cmd_vel is seen, then starts the curve server (t = 0). The runner's own monitor
(and recorder, with a bag) sample the run (observers.py); at the end, or on Ctrl-C, every node
is stopped with SIGINT and metrics and figures are written (run_experiment.py: the command's
run to its end, signals and results).
"""

from contextlib import ExitStack
import dataclasses
import json
import os
from pathlib import Path
import shutil
import threading
import time

from rclpy.serialization import serialize_message

from curve_formation.bags.analysis import bag_accounting, RUN_END_KEY
from curve_formation.bags.bag import BagWriter
from curve_formation.core.config.experiment import phase_index
from curve_formation.core.config.loading import control_rate, load_experiment
from curve_formation.dds_shm import remove_dead_shared_memory
from curve_formation.nodes.runtime import now_seconds
from curve_formation.nodes.topics import CURVE, DIAGNOSTICS
from curve_formation.paths import discovery_text, resolve_config, ros_environment, run_domain_id
from curve_formation.results.outputs import write_outputs
from curve_formation.results.provenance import provenance_text
from curve_formation.run.fleet_status import FleetStatus
from curve_formation.run.launches import (
    BRIDGE,
    bridged_fleet,
    grouped,
    GroupLaunch,
    held_robots,
    node_launches,
    part_of,
    poses_in_one_message,
)
from curve_formation.run.node_graph import NodeGraph
from curve_formation.run.observers import Observers
from curve_formation.run.preflight import (
    MissingRobotsError,
    PoseWatch,
    PreflightError,
    PreflightResult,
    run_preflight,
)
from curve_formation.run.run_options import DEFAULTS
from curve_formation.run.run_record import measured, status_line, STATUS_PERIOD
from curve_formation.run.start_scripts import write_node_files
from curve_formation.run.team_file import faults_of_team, write_team_file


READY_TIMEOUT = 90.0   # s; nine Python processes start in ~10 s on two cores
# s of discovery in which a curve server already on the domain is looked for before real
# robots' controllers start (seen found after 0 to 2.3 s under LOCALHOST); meanwhile the nodes
# that cannot move a robot start
FORMATION_CHECK = 3.0
# s between those looks while the run waits for its robots (a graph query: not after every
# message)
FORMATION_LOOK_PERIOD = 0.2


class FormationRunningError(ValueError):
    """A curve server already serves a formation on the run's domain."""


class Run:
    """A running node graph: start(), spin_until(...), stop(). Use as a context manager.

    Nothing is started nor written before start(), except that a bag path which exists is
    refused at once.
    """

    def __init__(self, experiment_path, out_dir, options=DEFAULTS, log=print):
        self.out = Path(out_dir)
        self.log = log
        self.stop_requested = threading.Event()   # set by run_experiment's signal handlers
        self._setup(experiment_path, options)

    def _setup(self, experiment_path, options):
        """The run of an experiment file, nothing started (again, for a team left short)."""
        self.experiment_path = resolve_config(experiment_path)
        self.experiment = load_experiment(self.experiment_path)
        self.options = options
        if options.agents and max(options.agents) > self.experiment.n:
            raise ValueError(f'--agents: agent {max(options.agents)} is not in 1..'
                             f'{self.experiment.n} ({self.experiment.name})')
        self.rate_hz = control_rate(self.experiment, options.rate_hz)
        self.fleet = bridged_fleet(self.experiment, options, self.out / 'links')
        self.launches = node_launches(self.experiment, self.experiment_path, options,
                                      self.out / 'links', fleet=self.fleet)
        # the pre-flight's result (None: none ran) and, where robots were left out, the
        # first one's, of the whole team, with {new agent: robot of the file} (team)
        self.preflight: PreflightResult | None = None
        self.fleet_status: FleetStatus | None = None   # with the observer
        self.left_out: dict | None = None
        self.domain_id = run_domain_id(options.isolated)
        self.publications_dir = self.out / 'publications'
        self.bag_writer = (None if options.bag_path is None
                           else BagWriter(options.bag_path, options.bag_storage))
        self.observers: Observers | None = None   # set by start()
        self.graph: NodeGraph | None = None
        self._stack = ExitStack()

    # -- lifecycle -------------------------------------------------------------------------
    def __enter__(self):
        try:
            self.start()
        except BaseException:
            self.stop()   # a start that timed out must not leave node processes running
            raise
        return self

    def __exit__(self, *exc):
        self.stop()

    def start(self):
        """Start the node graph (see the module); with robots behind links, pre-flight first.
        Robots that fail it and may be missing (allow_missing) are left out: the graph is
        stopped and started again with the team without them (team.yaml in the output
        folder).
        """
        try:
            self._start()
        except MissingRobotsError as leave:
            self._restart_without(leave.result)

    def _start(self):
        options = self.options
        params_files, _ = write_node_files(self.launches, self.out, self.experiment.name,
                                           group_size=options.group_size(self.experiment.n))
        recording = self.bag_writer is not None
        if recording:
            self.publications_dir.mkdir(parents=True, exist_ok=True)
        self._stack.enter_context(ros_environment(self.domain_id, options.discovery_server,
                                                  options.isolated))
        self.observers = self._stack.enter_context(Observers(
            self.experiment, options.record_hz,
            ground_truth=options.camera is not None and options.with_robots,
            bag_writer=self.bag_writer, images=options.bag_images,
            experiment_text=self.experiment_path.read_text(),
            provenance_text=provenance_text(self.experiment_path),
            parameters_text='\n'.join(path.read_text() for path in params_files.values()),
            watch=options.runs('observer') or options.runs('curve_server'),
            poses_from_all=poses_in_one_message(self.experiment, options)))
        if options.runs('observer'):
            self.fleet_status = FleetStatus(self.observers.monitor)
        self.graph = self._stack.enter_context(NodeGraph(
            self.launches, params_files, self.out / 'logs', self.observers,
            options.single_process, self.publications_dir if recording else None))
        self.graph.on_death = self._on_death
        if recording:
            self.log(f'recording {options.bag_path}')
        self.log(f'{self.where()}{" (isolated)" if options.isolated else ""}; parameters in '
                 f'{self.out / "params"}, start scripts in {self.out}')
        server, *others = self.launches
        ours = [launch for launch in others   # every node of this host but the curve server
                if options.runs(part_of(launch.module)) and options.runs_agent(launch.agent)]
        # what can move a robot: the controllers, and the bridges (which also hold the
        # robots' links, so the pre-flight goes first)
        moving = [launch for launch in ours if part_of(launch.module) == 'controllers'
                  or launch.module == BRIDGE]
        for launch in ours:   # what cannot move a robot starts while the domain is looked at
            if launch not in moving:
                self.graph.start(launch)
        if options.runs('curve_server') and not options.with_robots:
            # Real robots: none is driven before the domain was looked at for
            # FORMATION_CHECK s.
            self._look_for_another_formation()
        if self.fleet and options.preflight and options.runs('robots'):
            self._preflight()
        self._start_moving(moving)
        early = options.runs('curve_server') and options.with_robots
        if early:
            if not options.isolated:   # simulated robots have started: no curve before the look
                self._look_for_another_formation()
            # The server starts with the simulated robots and waits for their poses itself,
            # so that its discovery overlaps theirs (50 robots: the first curve 4 s after
            # the robots were seen, started after them; 9 robots on the lab's domain: started
            # in 5.5-6.9 s against 7.3 s when the look came first).
            self.graph.start(server, overrides={'wait_for_poses': True})
        if options.runs('curve_server'):
            self._wait_ready(look=not early)
            if not early:
                # Every robot's pose has come (the monitor's): the server need not wait for
                # them again (its own subscriptions found the robots 2-3 s later, measured),
                # as it does started by hand from its parameters file.
                self.graph.start(server, overrides={'wait_for_poses': False})
        self.spin_until(lambda: self.monitor.t0 is not None, READY_TIMEOUT, 'the first curve')
        self.log('curve server started: t = 0' if options.runs('curve_server')
                 else 'first curve received: t = 0')
        if options.realtime_priority and not options.single_process:
            self._say_priority(options.realtime_priority)

    def _say_priority(self, priority):
        """Say whether the controllers' processes took the realtime priority asked (a
        process that could not says why in its log).
        """
        normal = []
        for key, proc in self.processes.items():
            try:
                if 'controller' in key and os.sched_getscheduler(proc.pid) != os.SCHED_FIFO:
                    normal.append(key)
            except OSError:   # ended meanwhile: its death is reported
                pass
        self.log(f'realtime priority {priority} not taken by {", ".join(sorted(normal))} '
                 '(their logs say why): they run at normal priority' if normal else
                 f'controllers at realtime priority {priority}')

    def _start_moving(self, moving):
        """Start the bridges, then the controllers: a process each, or grouped
        (RunOptions.group_size) into processes keyed controllers_<first>-<last>.
        """
        graph = self._started()[1]
        controllers = [launch for launch in moving if part_of(launch.module) == 'controllers']
        for launch in moving:
            if launch not in controllers:
                graph.start(launch)
        for unit in grouped(controllers, self.options.group_size(self.experiment.n)):
            if isinstance(unit, GroupLaunch):
                graph.start_group(unit)
            else:
                graph.start(unit)

    def _preflight(self):
        """Pre-flight of the robots behind links (run.preflight), published latched on
        /formation/preflight; PreflightError if a robot fails that may not be missing,
        MissingRobotsError if only such robots fail.
        """
        observers, _ = self._started()
        watch = PoseWatch(self.experiment.n, context=observers.context)
        observers.add_node(watch)

        def spin(seconds):   # every callback that comes within `seconds`
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                if self.stop_requested.is_set():
                    raise KeyboardInterrupt('stop requested')
                observers.spin_once(max(end - time.monotonic(), 0.0))
        result = self.preflight = run_preflight(self.experiment, self.fleet, watch, spin,
                                                self.log)
        if self.left_out is not None:
            result.left_out = [robot['robot'] for robot in self.left_out['robots']]
        watch.stop_watching()
        watch.publisher.publish(result.message(now_seconds(watch)))
        self.out.mkdir(parents=True, exist_ok=True)
        (self.out / 'preflight.json').write_text(json.dumps(result.as_dict(), indent=2))
        if result.passed:
            return
        failing = set(result.failing)
        if result.problems or not failing <= self.options.allow_missing:
            allowed = ','.join(map(str, sorted(failing)))
            raise PreflightError(result, '' if result.problems
                                 else f'--allow-missing {allowed} runs the others')
        raise MissingRobotsError(result)

    def _restart_without(self, result):
        """Stop what started, and start again with the team without the robots that failed
        the pre-flight `result` (team.yaml in the output folder; an aborted bag removed: it
        held the pre-flight's seconds only, and the new one records its result).
        """
        missing = set(result.failing)
        self.log(f'pre-flight: robots {sorted(missing)} left out (--allow-missing); starting '
                 'again with the others')
        self.stop()
        if self.options.bag_path is not None and Path(self.options.bag_path).exists():
            shutil.rmtree(self.options.bag_path)
        path = write_team_file(self.experiment_path, missing, self.out / 'team.yaml')
        kept = [i for i in range(1, self.experiment.n + 1) if i not in missing]
        left_out = {'robots': [robot.as_dict() for robot in result.robots
                               if robot.agent in missing],
                    'team': {str(new): old for new, old in enumerate(kept, 1)}}
        number = {old: new for new, old in enumerate(kept, 1)}
        options = dataclasses.replace(self.options, allow_missing=frozenset(),
                                      faults=faults_of_team(self.options.faults, number))
        self._setup(path, options)
        self.left_out = left_out
        self._start()

    def wind_down(self):
        """Stop every node and close the bag after their last messages, keeping the
        observers' ROS entities: what the run measured is complete (measure) before stop()
        lets go of DDS, which can hang (Observers.finish).
        """
        self.end()
        if self.graph is not None:
            self.graph.stop()
        if self.observers is not None:
            self.observers.finish()

    def stop(self):
        """Stop every node, then the observers (the bag is closed after the nodes' last
        messages were recorded); give the environment back.
        """
        self.wind_down()
        self._stack.close()
        if self.bag_writer is not None:
            self.bag_writer.close()   # also when start() never opened it
        if self.graph is not None and self.graph.ended_hard:
            remove_dead_shared_memory()

    def end(self):
        """The run ends here (once), before its nodes are stopped or its results written: the
        monitor samples no more and the bag says when (analysis.RUN_END_KEY). What the nodes do
        while they stop, or while nobody reads their messages, is not the run.
        """
        if self.observers is None or self.observers.monitor is None or self.monitor.closed:
            return
        self.monitor.close()
        if self.bag_writer is not None:
            now = self.monitor.get_clock().now().nanoseconds
            self.bag_writer.set_custom(RUN_END_KEY, str(now))

    def _started(self) -> tuple[Observers, NodeGraph]:
        """The run's observers and node graph; RuntimeError before start()."""
        if self.observers is None or self.graph is None:
            raise RuntimeError('the run has not started (Run.start, or enter it)')
        return self.observers, self.graph

    @property
    def monitor(self):
        return self._started()[0].monitor

    @property
    def recorder(self):
        return self._started()[0].recorder

    @property
    def processes(self):
        return self._started()[1].processes

    def _on_death(self, death):
        """A node process ended on its own: said now, written into the bag (a /diagnostics
        message, diagnostics.NODE_DEATH_REPORTER) and later into metrics.json; the run goes on
        without it.
        """
        t, report = self.monitor.report_death(death.key, death.how)
        if self.bag_writer is not None:
            self.bag_writer.write(DIAGNOSTICS, self.monitor.get_clock().now().nanoseconds,
                                  serialize_message(report))
        when = 'before t = 0' if t is None else f'at t = {t:.1f} s'
        held = held_robots(death.key)
        robots = f' with the controllers of robots {held}' if len(held) > 1 else ''
        self.log(f'node {death.key} died {when} ({death.how}){robots}; the run goes on '
                 f'without it (its log: {self.out / "logs" / (death.key + ".log")})')

    def _look_for_another_formation(self):
        """Spin FORMATION_CHECK s (less if one is found) looking for another formation on
        the domain, then refuse to go on if there is one (_refuse_another_formation).
        """
        try:
            self.spin_until(self._another_formation, FORMATION_CHECK, 'a curve server')
        except TimeoutError:
            pass
        self._refuse_another_formation()

    def _another_formation(self):
        """Whether a curve server other than ours (not started yet) serves this domain."""
        monitor = self.monitor
        return monitor.t0 is not None or monitor.count_publishers(CURVE) > 0

    def _refuse_another_formation(self):
        """FormationRunningError if a curve server already serves this domain: its curve
        would drive our robots, and our server would drive its robots.
        """
        if not self._another_formation():
            return
        raise FormationRunningError(
            f'a formation is already running on ROS_DOMAIN_ID={self.domain_id} (discovery '
            f'{discovery_text()}): a curve server serves it; stop it first, or run on another '
            'domain (ROS_DOMAIN_ID=N, or --isolated for a private one)')

    def where(self):
        """Where this run's nodes meet, for every waiting line: domain and discovery."""
        return f'ROS_DOMAIN_ID={self.domain_id}, discovery {discovery_text()}'

    def waiting_hint(self):
        hint = f'({self.where()}'
        if not self.options.with_robots:
            hint += ("; are the robots' drivers (or robot_bridge and its robot) up on this "
                     'domain, and is the camera tracker running?')
        return hint + ')'

    def _wait_ready(self, look=True):
        """Spin until every robot's pose and cmd_vel is seen, saying what is missing every
        STATUS_PERIOD s; with the curve server here (and `look`: not started yet), another
        formation on the domain is looked for every FORMATION_LOOK_PERIOD s meanwhile and
        once more at the end.
        """
        said = [time.monotonic()]
        looked = [time.monotonic()]
        ours = self.options.runs('curve_server') and look

        _, graph = self._started()

        def ready():
            graph.check_processes()
            if graph.deaths:   # a node that cannot start: a set-up error, not a run's
                death = graph.deaths[0]
                raise RuntimeError(f'node {death.key} ended while starting ({death.how}):\n'
                                   f'{death.log_tail}')
            now = time.monotonic()
            if ours and now - looked[0] >= FORMATION_LOOK_PERIOD:
                looked[0] = now
                self._refuse_another_formation()
            if now - said[0] >= STATUS_PERIOD:
                said[0] = now
                self.log(f'waiting for {", ".join(self.monitor.missing())} '
                         f'{self.waiting_hint()}')
            return self.monitor.ready()
        try:
            self.spin_until(ready, READY_TIMEOUT, "every robot's pose and cmd_vel")
        except TimeoutError as exc:
            raise TimeoutError(f'{exc}; missing: {", ".join(self.monitor.missing())} '
                               f'{self.waiting_hint()}') from None
        if ours:
            self._refuse_another_formation()

    def status(self):
        """One line on the run now (run_record.status_line); None before t = 0."""
        return status_line(self)

    def spin_until(self, predicate, timeout, what='a condition'):
        """Spin the monitor (and in-process nodes) until predicate() or timeout (s).

        KeyboardInterrupt once stop_requested is set: a signal handler only sets it, because
        an exception raised inside an rclpy call (e.g. while a message is being converted)
        comes out as a RuntimeError ("Unable to convert call argument"), not as an interrupt.
        """
        deadline = time.monotonic() + timeout
        while not predicate():
            if self.stop_requested.is_set():
                raise KeyboardInterrupt('stop requested')
            if time.monotonic() > deadline:
                raise TimeoutError(f'timed out after {timeout:g} s waiting for {what}')
            self._started()[0].spin_once()

    def spin_for(self, seconds, status_every=None):
        """Spin `seconds`; with status_every (s), log status() that often."""
        end = time.monotonic() + seconds
        said = [time.monotonic()]

        def done():
            if status_every and time.monotonic() - said[0] >= status_every:
                said[0] = time.monotonic()
                line = self.status()
                if line:
                    self.log(line)
            return time.monotonic() >= end or self._started()[1].check_processes()
        self.spin_until(done, seconds + 5)

    # -- results ---------------------------------------------------------------------------
    def recording(self):
        return self.monitor.recording.arrays()

    def write_results(self, label='ROS run'):
        """The run's folder (outputs.write_outputs: metrics.json, figures, trajectory.npz,
        report.html) from what the monitor recorded (measure); returns its metrics.
        """
        experiment, record, result = self.measure()
        write_outputs(self.out, experiment, record, result, self.experiment_path, label=label,
                      animate=self.options.animate)
        return result

    def measure(self):
        """(experiment as followed, record, metrics) of what the monitor recorded, for
        outputs.write_outputs (run_record.measured); the run ends first (end). RuntimeError
        if nothing was.
        """
        self.end()
        return measured(self)

    def bag_accounting(self):
        """analysis.bag_accounting of the run's bag, once stopped: what was lost per topic."""
        return bag_accounting(self.options.bag_path, self.publications_dir,
                              self.recorder.streams, self._started()[0].best_effort_topics)

    def followed(self, t):
        """(experiment, phase): the experiment with the phases the run followed, i.e. the
        curves and agents' parameters the monitor received (core.config.experiment.ReceivedPhases,
        re-assignments included), and the phase index of each sample time t (R,) s.
        """
        phases = self.monitor.followed_phases()
        return (dataclasses.replace(self.experiment, phases=phases),
                phase_index([p.start for p in phases], t))
