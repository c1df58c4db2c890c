"""`curve-formation run`: one experiment YAML -> a ROS 2 node graph, run, measured.

Writes one parameters file per node into OUT/params/ (usable by hand with `ros2 run ...
--ros-args -r __ns:=/robot_3 --params-file OUT/params/robot_3.formation_controller.yaml`),
starts every node as its own process (or all in one executor with single_process), waits until
every robot's pose and every controller's cmd_vel is seen, then starts the curve server (t = 0).
A monitor node in this process samples poses, commands and estimates; at the end (or on
Ctrl-C) all nodes are stopped with SIGINT and metrics and figures are written.
"""

import dataclasses
from dataclasses import dataclass
import json
import os
from pathlib import Path
import random
import signal
import socket
import subprocess
import sys
import threading
import time

import numpy as np
import yaml

from curve_formation.analysis import EXPERIMENT_KEY
from curve_formation.bag import DEFAULT_STORAGE
from curve_formation.core import metrics, plots, wire
from curve_formation.core.agent import agent_configs
from curve_formation.core.config_schema import LimitsSpec
from curve_formation.core.experiment import control_rate, load_experiment, received_phases
from curve_formation.nodes.formation_controller import node_parameters
from curve_formation.nodes.params import limit_parameter
from curve_formation.nodes.runtime import (
    make_executor,
    PublicationCounter,
    PUBLICATIONS_ENV,
    spin_until_quiet,
    stream_topic,
)
from curve_formation.paths import resolve_config


# Keys of the bag metadata (custom_data) that make a bag self-describing.
PARAMETERS_KEY = 'curve_formation.parameters'
READY_TIMEOUT = 90.0   # s; nine Python processes start in ~10 s on two cores
STOP_TIMEOUT = 10.0    # s for a group of nodes to exit after SIGINT before it is killed
PROCESS_CHECK_PERIOD = 0.2   # s between checks that every node process still runs


@dataclass(frozen=True)
class NodeLaunch:
    """One node to start: its module, namespace, name and parameters."""

    module: str
    namespace: str
    name: str
    parameters: dict

    @property
    def key(self):
        return f'{self.namespace.strip("/") + "." if self.namespace != "/" else ""}{self.name}'


def node_launches(experiment, experiment_path, with_robots=True, rate_hz=None,
                  pose_noise=(0.0, 0.0), command_latency=0.0, faults=None, camera=None,
                  bridge=None, links_dir=None):
    """The node graph of an experiment: curve server, controllers and (optionally) fake robots.

    faults: fault injection, {'pose_drop': p, 'state_drop': p, 'link_down': [robot, from,
    for]}.
    bridge: None, or 'udp' or 'pty': every controller's cmd_vel goes through a robot_bridge
    over a UDP port or a pseudo-terminal (in links_dir) to the emulated robots of fake_arena.
    camera: None, or fake_camera parameter overrides ({} for none): poses then come from
    camera_tracker, fed by fake_camera rendering the fake robots (with_robots) or by a real
    camera driver on /camera/image_raw.
    """
    faults = faults or {}
    spec = experiment.spec
    if camera is not None and spec.camera is None:
        raise ValueError(f'{experiment.source}: camera: a camera run needs a `camera` section')
    cameras = ([] if camera is None
               else camera_launches(experiment, experiment_path, with_robots, camera))
    rate = control_rate(experiment, rate_hz)
    on_pc = spec.disturbance.injected == 'on_pc'
    one_world = uses_fake_arena(experiment) or bridge is not None
    links = robot_links(experiment.n, bridge, links_dir) if bridge and with_robots else []
    # The curve server waits until the n controllers, the runner's monitor and the camera nodes
    # (they draw the curve) can receive from it (nodes/readiness.py).
    launches = [NodeLaunch('curve_formation.nodes.curve_server', '/', 'curve_server',
                           {'experiment': str(Path(experiment_path).resolve()),
                            'wait_for_ready': experiment.n + 1 + len(cameras)})]
    for i, config in enumerate(agent_configs(experiment, rate), 1):
        ns = f'/robot_{i}'
        d = [float(v) for v in experiment.disturbance[i - 1]]
        controller = {**node_parameters(config),
                      'fault_state_drop': float(faults.get('state_drop', 0.0))}
        launches.append(NodeLaunch('curve_formation.nodes.formation_controller', ns,
                                   'formation_controller', controller))
        if links:
            launches.append(NodeLaunch('curve_formation.nodes.robot_bridge', ns,
                                       'robot_bridge', bridge_parameters(experiment, rate,
                                                                         links[i - 1])))
        if with_robots and not one_world:
            launches.append(NodeLaunch('curve_formation.nodes.fake_robot', ns, 'fake_robot', {
                'index': i,
                'initial_pose': [float(v) for v in experiment.initial_poses[i - 1]],
                'disturbance': [0.0, 0.0] if on_pc else d, 'seed': i,
                'pose_noise': [float(v) for v in pose_noise],
                'command_latency': float(command_latency),
                'fault_pose_drop': float(faults.get('pose_drop', 0.0)),
                'pose_topic': 'pose' if camera is None else 'true_pose'}))
    if with_robots and one_world:
        arena = {'experiment': str(Path(experiment_path).resolve()),
                 'pose_noise': [float(v) for v in pose_noise],
                 'command_latency': float(command_latency),
                 'fault_pose_drop': float(faults.get('pose_drop', 0.0)),
                 'pose_topic': 'pose' if camera is None else 'true_pose',
                 'publish_robot_poses': camera is None}
        if links:   # emulated robots behind their links, reading what the bridges write
            arena['links'] = links
            arena['wheel_radius'] = wheel_radius(experiment)
            if 'link_down' in faults:
                arena['fault_link_down'] = [float(v) for v in faults['link_down']]
        launches.append(NodeLaunch('curve_formation.nodes.fake_arena', '/', 'fake_arena',
                                   arena))
    return launches + cameras


# Ports for the emulated robots' UDP links: below the kernel's ephemeral range (32768 and up
# here), where a socket bound to port 0 (each bridge's own) could take a probed port before
# fake_arena binds it (seen once in a full test run), and below Fast DDS's ports (7400 + 250
# x domain id and up).
LINK_PORTS = range(6000, 7400)


def robot_links(n, bridge, folder, rng=None):
    """Each robot's link, as the emulated robot listens on it: a free UDP port on this
    machine (from LINK_PORTS), or a pseudo-terminal at folder/robot_<i>.
    """
    if bridge == 'pty':
        return [f'pty:{Path(folder).resolve() / f"robot_{i}"}' for i in range(1, n + 1)]
    if bridge != 'udp':
        raise ValueError(f"bridge must be 'udp' or 'pty', got {bridge!r}")
    rng = rng or random.SystemRandom()
    ports = []
    for port in rng.sample(LINK_PORTS, len(LINK_PORTS)):
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
            try:
                probe.bind(('127.0.0.1', port))
            except OSError:
                continue
        ports.append(port)
        if len(ports) == n:
            return [f'udp:127.0.0.1:{port}' for port in ports]
    raise RuntimeError(f'no {n} free UDP ports in {LINK_PORTS}')


def wheel_radius(experiment):
    """The experiment's wheel radius (m; the schema's default without a limits section)."""
    limits = experiment.spec.limits
    return float(limits.wheel_radius if limits
                 else LimitsSpec.model_fields['wheel_radius'].default)


def bridge_parameters(experiment, rate, link):
    """robot_bridge parameters for a robot behind `link` (the emulated robot's end of it)."""
    limits = experiment.limits
    kind, _, where = link.partition(':')
    return {'link': link if kind == 'udp' else f'serial:{where}',
            'wheel_base': float(limits.wheel_base or wire.MONA_WHEEL_BASE),
            'wheel_radius': wheel_radius(experiment),
            'max_wheel_speed': limit_parameter(limits.max_wheel_speed),
            'rate_hz': float(rate)}


def uses_fake_arena(experiment):
    """Simulated robots share one world (fake_arena) when they have bodies or avoid each
    other; otherwise each is a fake_robot of its own, passing through the others.
    """
    return experiment.radius > 0 or experiment.avoidance.on


def camera_launches(experiment, experiment_path, with_fake_camera, overrides):
    """camera_tracker, and fake_camera (with the experiment's fake settings) when simulated."""
    cam = experiment.spec.camera
    path = str(Path(experiment_path).resolve())
    launches = [NodeLaunch('curve_formation.nodes.camera_tracker', '/', 'camera_tracker',
                           {'experiment': path})]
    if with_fake_camera:
        fake = cam.fake
        launches.append(NodeLaunch('curve_formation.nodes.fake_camera', '/', 'fake_camera', {
            'experiment': path, 'rate_hz': float(cam.rate_hz),
            'resolution': [int(v) for v in cam.resolution], 'tilt_deg': float(fake.tilt_deg),
            'height': float(fake.height), 'noise': float(fake.noise),
            'blur': float(fake.blur), 'brightness': float(fake.brightness), **overrides}))
    return launches


def write_params_files(launches, folder):
    """One ROS 2 parameters file per node; returns {key: path}."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = {}
    for launch in launches:
        fqn = (launch.namespace.rstrip('/') + '/' + launch.name)
        path = folder / f'{launch.key}.yaml'
        path.write_text(yaml.safe_dump({fqn: {'ros__parameters': launch.parameters}},
                                       sort_keys=False))
        paths[launch.key] = path
    return paths


def private_domain_id():
    """ROS_DOMAIN_ID from the environment, else a random one in 1..101 for this run."""
    given = os.environ.get('ROS_DOMAIN_ID')
    return int(given) if given else random.SystemRandom().randint(1, 101)


DISCOVERY_SERVER_ENV = 'ROS_DISCOVERY_SERVER'
RANGE_ENV = 'ROS_AUTOMATIC_DISCOVERY_RANGE'


def use_discovery(env):
    """Sets the run's discovery in `env`: limited to this machine (LOCALHOST) unless
    ROS_AUTOMATIC_DISCOVERY_RANGE says otherwise; with ROS_DISCOVERY_SERVER (a Fast DDS
    discovery server, for networks where multicast fails), SUBNET: with LOCALHOST or OFF the
    server's clients discovered nothing (measured: a run's start timed out). A server with
    one of those ranges is a ValueError naming both variables.
    """
    if env.get(DISCOVERY_SERVER_ENV):
        chosen = env.setdefault(RANGE_ENV, 'SUBNET')
        if chosen in ('LOCALHOST', 'OFF'):
            raise ValueError(f'{DISCOVERY_SERVER_ENV}={env[DISCOVERY_SERVER_ENV]} with '
                             f'{RANGE_ENV}={chosen}: Fast DDS discovery-server clients '
                             'discover nothing in that range; unset it or set SUBNET')
    else:
        env.setdefault(RANGE_ENV, 'LOCALHOST')


class Run:
    """A running node graph: start(), spin_until(...), stop(). Use as a context manager."""

    def __init__(self, experiment_path, out_dir, single_process=False, with_robots=True,
                 rate_hz=None, record_hz=20.0, pose_noise=(0.0, 0.0), command_latency=0.0,
                 bag_path=None, faults=None, camera=None, bag_images=False, log=print,
                 bag_storage=DEFAULT_STORAGE, bridge=None):
        self.experiment_path = resolve_config(experiment_path)
        self.bag_images = bag_images
        self.experiment = load_experiment(self.experiment_path)
        self.out = Path(out_dir)
        self.single_process = single_process
        self.log = log
        self.rate_hz = control_rate(self.experiment, rate_hz)
        self.camera = camera
        self.with_robots = with_robots
        self.launches = node_launches(self.experiment, self.experiment_path, with_robots,
                                      rate_hz, pose_noise, command_latency, faults, camera,
                                      bridge, self.out / 'links')
        self.param_files = write_params_files(self.launches, self.out / 'params')
        self.domain_id = private_domain_id()
        self._saved_env = {}   # environment variables start() set, with their old values
        self.record_hz = record_hz
        self.processes = {}
        self.stop_requested = threading.Event()   # set by run_experiment's signal handlers
        self._last_process_check = -np.inf
        # Set by start(); stop() takes down whatever of them exists.
        self.context = self.executor = self.monitor = self.recorder = None
        self.in_process_nodes = []
        self.bag_writer = None
        self.counters = []
        self.best_effort_topics = set()
        self.publications_dir = self.out / 'publications'
        if bag_path is not None:
            self.publications_dir.mkdir(parents=True, exist_ok=True)
            from curve_formation.bag import BagWriter
            # refuses an existing path before any start
            self.bag_writer = BagWriter(bag_path, bag_storage)

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
        # Set for this process's own context and the nodes', given back at stop().
        self._saved_env = {k: os.environ.get(k) for k in ('ROS_DOMAIN_ID', RANGE_ENV)}
        use_discovery(os.environ)
        os.environ['ROS_DOMAIN_ID'] = str(self.domain_id)

        import rclpy
        from rclpy.context import Context
        from rclpy.qos import ReliabilityPolicy
        from rclpy.signals import SignalHandlerOptions

        from curve_formation.nodes.monitor import Monitor
        self.rclpy = rclpy
        self.context = Context()
        # Signals stay with Python (Ctrl-C, or run_experiment's handlers), so that stop() can
        # close the bag and stop the nodes.
        rclpy.init(context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        self.monitor = Monitor(self.experiment.n, self.record_hz, context=self.context,
                               ground_truth=self.camera is not None and self.with_robots)
        # The same executor as every node process (callbacks dispatched from C++). Python
        # callbacks share the GIL: more executor threads would not run them faster.
        self.executor = make_executor(self.context)
        self.executor.add_node(self.monitor)
        if self.bag_writer is not None:
            from curve_formation.nodes import topics
            from curve_formation.nodes.recorder import Recorder
            self.bag_writer.__enter__()
            self.bag_writer.set_custom(EXPERIMENT_KEY, self.experiment_path.read_text())
            self.bag_writer.set_custom(PARAMETERS_KEY, '\n'.join(
                path.read_text() for path in self.param_files.values()))
            recorded = topics.recorded(self.experiment.n, self.bag_images)
            self.best_effort_topics = {t.name for t in recorded
                                       if t.profile.reliability == ReliabilityPolicy.BEST_EFFORT}
            self.recorder = Recorder(self.bag_writer, recorded, context=self.context)
            self.executor.add_node(self.recorder)
            self.log(f'recording {self.bag_writer.path}')
        server = os.environ.get(DISCOVERY_SERVER_ENV)
        discovery = os.environ[RANGE_ENV] + (f' through the server {server}' if server else '')
        self.log(f'ROS_DOMAIN_ID={self.domain_id}, discovery {discovery}; parameters in '
                 f'{self.out / "params"}')
        robots = [launch for launch in self.launches if launch.name != 'curve_server']
        for launch in robots:
            self._start_node(launch)
        self._wait_ready()
        self._start_node(self.launches[0])
        self.spin_until(lambda: self.monitor.t0 is not None, READY_TIMEOUT, 'the first curve')
        self.log('curve server started: t = 0')

    def _start_node(self, launch):
        if self.single_process:
            node = _node_class(launch.module)(
                context=self.context, namespace=launch.namespace,
                parameter_overrides=_overrides(launch.parameters))
            self.in_process_nodes.append(node)
            if self.bag_writer is not None:
                self.counters.append((node, PublicationCounter(node)))
            self.executor.add_node(node)
            return
        logs = self.out / 'logs'
        logs.mkdir(parents=True, exist_ok=True)
        env = dict(os.environ, ROS_DOMAIN_ID=str(self.domain_id), PYTHONUNBUFFERED='1')
        if self.bag_writer is not None:   # each node reports what it published
            env[PUBLICATIONS_ENV] = str(self.publications_dir)
        cmd = [sys.executable, '-m', launch.module, '--ros-args', '-r',
               f'__ns:={launch.namespace}', '--params-file', str(self.param_files[launch.key])]
        with open(logs / f'{launch.key}.log', 'w') as log_file:
            self.processes[launch.key] = subprocess.Popen(
                cmd, env=env, stdout=log_file, stderr=subprocess.STDOUT,
                start_new_session=True, preexec_fn=_stop_with_parent)

    def _wait_ready(self):
        def ready():
            self.check_processes()
            return self.monitor.ready()
        try:
            self.spin_until(ready, READY_TIMEOUT, "every robot's pose and cmd_vel")
        except TimeoutError as exc:
            raise TimeoutError(f'{exc}; missing: {self.monitor.missing()}') from None

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
            self.executor.spin_once(timeout_sec=0.02)

    def spin_for(self, seconds):
        end = time.monotonic() + seconds
        self.spin_until(lambda: time.monotonic() >= end or self.check_processes(), seconds + 5)

    def check_processes(self):
        """Raise if a node process ended on its own; returns False otherwise.

        Looks at most every PROCESS_CHECK_PERIOD s (it is called between callbacks).
        """
        now = time.monotonic()
        if now - self._last_process_check < PROCESS_CHECK_PERIOD:
            return False
        self._last_process_check = now
        for key, proc in self.processes.items():
            if proc.poll() is not None:
                tail = (self.out / 'logs' / f'{key}.log').read_text()[-2000:]
                raise RuntimeError(f'node {key} exited with status {proc.returncode}:\n{tail}')
        return False

    def kill(self, key, sig=signal.SIGKILL):
        """Kill one node process (fault injection); it is forgotten by check_processes."""
        proc = self.processes.pop(key)
        proc.send_signal(sig)
        proc.wait(10)
        return proc.returncode

    def restart(self, key):
        self._start_node(next(launch for launch in self.launches if launch.key == key))

    def stop(self):
        """SIGINT every node (they send a last zero command), then kill what lingers.

        The bag, if any, is closed last, after the nodes' final messages were recorded.
        """
        try:
            self._stop_nodes()
        finally:
            if self.bag_writer is not None:
                self.bag_writer.close()
            self._restore_env()

    def _restore_env(self):
        for key, value in self._saved_env.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value
        self._saved_env = {}

    def _stop_nodes(self):
        # Controllers first, so that their last ticks and zero commands are acknowledged by
        # the fake robots and the recorder, which are all still there; the runner spins
        # meanwhile, so the recorder keeps draining its queue.
        first = {k: p for k, p in self.processes.items() if k.endswith('formation_controller')}
        for group in (first, {k: p for k, p in self.processes.items() if k not in first}):
            deadline = time.monotonic() + STOP_TIMEOUT   # for the whole group together
            for proc in group.values():
                if proc.poll() is None:
                    proc.send_signal(signal.SIGINT)
            while time.monotonic() < deadline and any(p.poll() is None for p in group.values()):
                if self.executor is not None:
                    self.executor.spin_once(timeout_sec=0.02)
                else:
                    time.sleep(0.02)
            for proc in group.values():
                if proc.poll() is None:
                    proc.kill()
                    proc.wait(5)
        self.processes = {}
        if self.context is None:
            return
        if self.executor is None:   # start() failed before the executor
            self.rclpy.try_shutdown(context=self.context)
            self.context = None
            return
        # Record what is still queued (the nodes' last zero commands among it).
        spin_until_quiet(self.executor, self._received)
        for node in self.in_process_nodes:
            hook = getattr(node, 'on_shutdown', None)
            if hook is not None:
                hook()
        for node, counter in self.counters:
            counter.save(self.publications_dir, node.get_fully_qualified_name())
        self.executor.shutdown(timeout_sec=1.0)
        for node in self.in_process_nodes + [self.monitor, self.recorder]:
            if node is not None:
                node.destroy_node()
        self.rclpy.try_shutdown(context=self.context)
        self.context = self.executor = None

    def _received(self):
        return 0 if self.bag_writer is None else self.bag_writer.count

    # -- results ---------------------------------------------------------------------------
    def recording(self):
        return self.monitor.recording.arrays()

    def write_results(self, label='ROS run'):
        """metrics.json, figures and trajectory.npz from what the monitor recorded."""
        data = self.recording()
        if len(data['t']) < 2:
            raise RuntimeError('nothing was recorded')
        experiment, phase = self.followed(data['t'])
        camera = len(data['true_poses']) == len(data['t'])
        truth = data['true_poses'] if camera else data['poses']
        result = metrics.run_metrics(experiment, data['t'], data['poses'], phase,
                                     data['dhat'], data['commands'])
        if 'bodies' in result:   # measured on the bodies, i.e. the true poses
            result['bodies'] = metrics.body_metrics(experiment, data['t'], truth,
                                                    self.monitor.contacts,
                                                    data['unseen'] if camera else None)
        if self.monitor.links:   # robot_bridge's link reports, per robot
            result['links'] = {name.strip('/').split('/')[0]: metrics.link_summary(reports)
                               for name, reports in sorted(self.monitor.links.items())}
        result['control'] = f'ROS nodes at {self.rate_hz:g} Hz'
        result['mode'] = 'single process' if self.single_process else 'one process per node'
        if camera:
            result['ground_truth'] = ground_truth_metrics(experiment, data, phase)
        self.out.mkdir(parents=True, exist_ok=True)
        (self.out / 'metrics.json').write_text(metrics.strict_json(result))
        plots.run_figures(self.out, experiment, data['t'], data['poses'], phase,
                          data['dhat'], label=label)
        np.savez_compressed(self.out / 'trajectory.npz', phase=phase, **data)
        return result


    def followed(self, t):
        """(experiment, phase): the experiment with the phases the run followed, i.e. the
        curves and agents' parameters the monitor received (core.experiment.received_phases,
        re-assignments included), and the phase index of each sample time t (R,) s.
        """
        phases = received_phases(self.experiment, self.monitor.received_curves())
        starts = np.array([p.start for p in phases])
        phase = np.clip(np.searchsorted(starts, t, side='right') - 1, 0, len(phases) - 1)
        return dataclasses.replace(self.experiment, phases=phases), phase


def phases_of(curve_ids, phase_count):
    """Phase index per sample from the curve id seen (ids count up with the schedule)."""
    return np.clip(np.asarray(curve_ids, dtype=int), 0, phase_count - 1)


NODE_CLASSES = {'curve_formation.nodes.curve_server': 'CurveServer',
                'curve_formation.nodes.formation_controller': 'FormationController',
                'curve_formation.nodes.fake_robot': 'FakeRobot',
                'curve_formation.nodes.fake_arena': 'FakeArena',
                'curve_formation.nodes.robot_bridge': 'RobotBridge',
                'curve_formation.nodes.camera_tracker': 'CameraTracker',
                'curve_formation.nodes.fake_camera': 'FakeCamera'}


def _node_class(module):
    import importlib
    return getattr(importlib.import_module(module), NODE_CLASSES[module])


def _overrides(parameters):
    from rclpy.parameter import Parameter
    return [Parameter(name, value=value) for name, value in parameters.items()]


def run_experiment(config, out_dir, duration=None, single_process=False, with_robots=True,
                   rate_hz=None, bag_path=None, camera=None, bag_images=False, log=print,
                   bag_storage=DEFAULT_STORAGE, bridge=None):
    """Run an experiment's node graph for `duration` s (default: the file's) and measure it.

    Ctrl-C (SIGINT) and SIGTERM stop every node and close the bag; both only set
    Run.stop_requested, acted on between callbacks (see Run.spin_until).
    """
    run = Run(config, out_dir, single_process, with_robots, rate_hz, bag_path=bag_path,
              camera=camera, bag_images=bag_images, log=log, bag_storage=bag_storage,
              bridge=bridge)
    duration = run.experiment.spec.simulation.duration if duration is None else duration
    previous = {sig: signal.signal(sig, lambda *_: run.stop_requested.set())
                for sig in (signal.SIGINT, signal.SIGTERM)}
    interrupted = False
    try:
        run.start()
        run.spin_for(duration)
    except KeyboardInterrupt:
        interrupted = True
        log('interrupted: stopping every node')
    finally:
        run.stop()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    result = run.write_results()
    result['interrupted'] = interrupted
    if bag_path is not None:
        result['bag'] = {'path': str(bag_path), 'messages': run.bag_writer.count,
                         **bag_accounting(bag_path, run.publications_dir, run.recorder.streams,
                                          run.best_effort_topics)}
        (run.out / 'metrics.json').write_text(metrics.strict_json(result))
    return result


def bag_accounting(bag_path, publications_dir, streams, best_effort=()):
    """Per recorded topic: messages the nodes published, should have recorded, and recorded.

    A DDS writer numbers its samples 1, 2, ... in publish order, so a writer stream (see
    runtime.writer_key) of N publications whose first received sample was number f should
    have put N - f + 1 in the bag, however late the recorder was matched. `streams` is the
    recorder's tally (Recorder.streams). A stream never received counts whole, and so does
    one with several writers or out of order. `lost`: expected but not in the bag, summed over
    the reliable topics; `lost_best_effort`: the same over the `best_effort` topics (poses,
    images), whose samples DDS may drop by design.
    """
    from curve_formation.bag import bag_summary
    published, writers = {}, {}
    for path in Path(publications_dir).glob('*.json'):
        for key, count in json.loads(path.read_text()).items():
            published[key] = published.get(key, 0) + count
            writers[key] = writers.get(key, 0) + 1
    recorded = {topic: count for topic, (_, count) in bag_summary(bag_path).items()}

    topics = {t: {'published': 0, 'expected': 0, 'recorded': n, 'lost': 0,
                  'best_effort': t in best_effort} for t, n in sorted(recorded.items())}
    for key, count in published.items():
        name = stream_topic(key)
        if name not in recorded:   # a topic the bag does not record, e.g. RViz markers
            continue
        stream = streams.get(key, {'first': 1, 'received': 0, 'in_order': True})
        exact = writers[key] == 1 and stream['in_order']
        expected = count - stream['first'] + 1 if exact else count
        topic = topics[name]
        topic['published'] += count
        topic['expected'] += expected
        topic['lost'] += max(0, expected - stream['received'])
    for name, topic in topics.items():   # received but not written: the bag writer failed
        received = sum(s['received'] for s in streams.values() if s['topic'] == name)
        topic['lost'] += max(0, received - topic['recorded'])

    def lost(effort):
        return sum(v['lost'] for v in topics.values() if v['best_effort'] == effort)
    return {'topics': topics, 'lost': lost(False), 'lost_best_effort': lost(True),
            'published': sum(v['published'] for v in topics.values())}


def ground_truth_metrics(experiment, data, phase):
    """With a camera: the formation measured on the fake robots' true poses, and how far the
    tracked poses (what the controllers saw, up to a frame old) were from them.
    """
    truth = data['true_poses']
    seen = np.isfinite(truth).all(axis=2) & np.isfinite(data['poses']).all(axis=2)
    gap = np.linalg.norm(data['poses'][..., :2] - truth[..., :2], axis=2)[seen]
    turn = np.abs(np.angle(np.exp(1j * (data['poses'][..., 2] - truth[..., 2]))))[seen]
    out = metrics.run_metrics(experiment, data['t'], truth, phase)
    return {'final_error_norm': out['final_error_norm'],
            'phases': [{k: p[k] for k in ('settled', 'settle_time', 'final_error_norm')}
                       for p in out['phases']],
            'tracked_vs_true_position_rms': float(np.sqrt(np.mean(gap ** 2))),
            'tracked_vs_true_heading_rms_deg': float(np.degrees(np.sqrt(np.mean(turn ** 2))))}


def _stop_with_parent():
    """In a node process: receive SIGINT when the runner dies, even if it is killed hard."""
    try:
        import ctypes
        ctypes.CDLL('libc.so.6', use_errno=True).prctl(1, signal.SIGINT)  # PR_SET_PDEATHSIG
    except OSError:
        pass
