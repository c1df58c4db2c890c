"""The node graph of an experiment: which nodes to start, with which parameters.

Writes one parameters file per node (usable by hand with `ros2 run ... --ros-args -r
__ns:=/robot_3 --params-file OUT/params/robot_3.formation_controller.yaml`; start_scripts.py
writes those lines).
"""

from dataclasses import dataclass
import importlib
from pathlib import Path
import random
import socket

import yaml

from curve_formation import scheduling
from curve_formation.core.config.agents import agent_configs
from curve_formation.core.config.experiment import wheel_radius
from curve_formation.core.config.loading import control_rate
from curve_formation.core.config.parameters import node_parameters
from curve_formation.core.config.variations import variations_text
from curve_formation.fleet import bridge_parameters, emulated_fleet, fleet_robots
from curve_formation.interface import robot_index, robot_name, robot_namespace
from curve_formation.run.run_options import DEFAULTS, ROBOT_FAULTS, SOLO_TEAM


BRIDGE = 'curve_formation.nodes.robot_bridge'   # the node that holds a robot's link


@dataclass(frozen=True)
class NodeLaunch:
    """One node to start: its module, namespace, name and parameters; runs: the module to run
    in its place with the same parameters (RunOptions.node_variants; '' = the module itself).
    """

    module: str
    namespace: str
    name: str
    parameters: dict
    runs: str = ''

    @property
    def program(self):
        """The module that is run for this node."""
        return self.runs or self.module

    @property
    def agent(self):
        """The agent (1-based) whose node this is (namespace /robot_<i>), or None."""
        return robot_index(self.namespace)

    @property
    def key(self):
        return f'{self.namespace.strip("/") + "." if self.namespace != "/" else ""}{self.name}'


def node_launches(experiment, experiment_path, options=DEFAULTS, links_dir=None,
                  observed=True, fleet=None):
    """The node graph of an experiment: curve server, controllers and, as the RunOptions say,
    fake robots or one fake arena, robot bridges (their pseudo-terminals in links_dir) and
    the camera nodes. observed: a runner's monitor (and with a bag, its recorder) reads the
    run, and the curve server waits for it too; False for a graph started by hand. fleet:
    the robots behind bridges (fleet.FleetRobot; None: bridged_fleet's).
    """
    with_robots, camera = options.with_robots, options.camera
    pose_noise, command_latency = options.pose_noise, options.command_latency
    faults = options.faults or {}
    spec = experiment.spec
    if camera is not None and spec.camera is None:
        raise ValueError(f'{experiment.source}: camera: a camera run needs a `camera` section')
    cameras = ([] if camera is None
               else camera_launches(experiment, experiment_path, with_robots, camera))
    rate = control_rate(experiment, options.rate_hz)
    on_pc = spec.disturbance.injected == 'on_pc'
    varies = variations_text(experiment)   # the disturbance's changes, as JSON
    engine = options.physics or spec.physics.engine
    one_world = in_one_world(experiment, options)
    grouped = options.group_size(experiment.n) > 1
    all_poses = poses_in_one_message(experiment, options)
    if fleet is None:
        fleet = bridged_fleet(experiment, options, links_dir)
    # The curve server waits until the n controllers, the runner's monitor, its bag recorder
    # and the camera nodes (they draw the curve) can receive from it (nodes/readiness.py).
    observers = (1 + (options.bag_path is not None)) if observed else 0
    launches = [NodeLaunch('curve_formation.nodes.curve_server', '/', 'curve_server',
                           {'experiment': str(Path(experiment_path).resolve()),
                            'wait_for_ready': experiment.n + len(cameras) + observers,
                            # every robot's pose first, as the runner waits (by hand, nobody does)
                            'wait_for_poses': True,
                            # a drawn curve comes from the camera, not from the schedule
                            'schedule': not (cameras and spec.camera.drawn_curve is not None)})]
    for i, config in enumerate(agent_configs(experiment, rate), 1):
        ns = robot_namespace(i)
        d = [float(v) for v in experiment.disturbance[i - 1]]
        controller = {**node_parameters(config),
                      'disturbance_varies': varies if on_pc else '',
                      # compiled once a process for the controllers that share one
                      'compiled_law': grouped or options.single_process,
                      # a group's poses in one message (a fake arena's, a camera tracker's)
                      'pose_from_all': grouped and all_poses,
                      scheduling.PARAMETER: options.realtime_priority}
        module = 'curve_formation.nodes.formation_controller'
        launches.append(NodeLaunch(module, ns, 'formation_controller', controller,
                                   (options.node_variants or {}).get(module, '')))
        if fleet:
            launches.append(NodeLaunch('curve_formation.nodes.robot_bridge', ns,
                                       'robot_bridge',
                                       bridge_parameters(experiment, rate, fleet[i - 1])))
        if with_robots and not one_world:
            launches.append(NodeLaunch('curve_formation.nodes.fake_robot', ns, 'fake_robot', {
                'index': i,
                'initial_pose': [float(v) for v in experiment.initial_poses[i - 1]],
                'disturbance': [0.0, 0.0] if on_pc else d, 'seed': i,
                'disturbance_varies': '' if on_pc else varies,
                'pose_noise': [float(v) for v in pose_noise],
                'command_latency': float(command_latency),
                'command_jitter': float(options.command_jitter),
                'fault_pose_drop': float(faults.get('pose_drop', 0.0)),
                'pose_topic': 'pose' if camera is None else 'true_pose'}))
    if with_robots and one_world:
        arena = {'experiment': str(Path(experiment_path).resolve()),
                 'pose_noise': [float(v) for v in pose_noise],
                 'command_latency': float(command_latency),
                 'command_jitter': float(options.command_jitter),
                 'fault_pose_drop': float(faults.get('pose_drop', 0.0)),
                 'pose_topic': 'pose' if camera is None else 'true_pose',
                 'publish_robot_poses': camera is None, 'physics': engine}
        if fleet:   # emulated robots behind their links, reading what the bridges write
            arena['links'] = [robot.address.text for robot in fleet]
            arena['wheel_radius'] = wheel_radius(experiment)
            if 'link_down' in faults:
                arena['fault_link_down'] = [float(v) for v in faults['link_down']]
        for key in ROBOT_FAULTS:   # fake_arena's fault_<key>: the robots that have it
            if key in faults:
                arena[f'fault_{key}'] = [int(v) for v in faults[key]]
        launches.append(NodeLaunch('curve_formation.nodes.fake_arena', '/', 'fake_arena',
                                   arena))
    return launches + cameras


# Ports for the emulated robots' UDP links: below the kernel's ephemeral range (32768 and up
# here), where a socket bound to port 0 (each bridge's own) could take a probed port before
# fake_arena binds it (seen once in a full test run), and below Fast DDS's ports: 7400 + 250
# x domain id and up, and one port from 7000 up for every participant on the machine (0.0.0.0:
# 7000, 7001, ... in the order processes start: measured in a bridged run of 30 processes;
# with the range at 6000-7400 a participant took a probed port twice before fake_arena bound it).
LINK_PORTS = range(5000, 7000)


def robot_links(n, bridge, folder, rng=None):
    """Each robot's link, as the emulated robot listens on it: a free UDP port on this
    machine (from LINK_PORTS), or a pseudo-terminal at folder/robot_<i>.
    """
    if bridge == 'pty':
        return [f'pty:{Path(folder).resolve() / robot_name(i)}' for i in range(1, n + 1)]
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


def bridged_fleet(experiment, options, links_dir):
    """The robots a run drives through robot bridges: with simulated robots and a bridge,
    fake_arena's emulated ones (links in links_dir for pseudo-terminals); with real robots,
    the file's robots.fleet (none listed: their drivers are started by hand); else none.
    """
    if options.with_robots:
        if not options.bridge:
            return []
        return emulated_fleet(experiment, robot_links(experiment.n, options.bridge, links_dir))
    return fleet_robots(experiment)


def in_one_world(experiment, options):
    """Whether a run's simulated robots share one fake_arena: when they meet, sit behind
    links, or are many (a process each would cost a DDS participant and a Python interpreter
    per robot).
    """
    engine = options.physics or experiment.spec.physics.engine
    return (uses_fake_arena(experiment, engine) or options.bridge is not None
            or experiment.n > SOLO_TEAM)


def poses_in_one_message(experiment, options):
    """Whether a run's poses also come all together on /formation/robot_poses, from a
    camera tracker or from the one fake_arena, each frame's the same as the robots' own.
    """
    return options.camera is not None or (options.with_robots
                                          and in_one_world(experiment, options))


def uses_fake_arena(experiment, engine='kinematic'):
    """Simulated robots share one world (fake_arena) when they have bodies or avoid each
    other, or live in MuJoCo (engine); otherwise each is a fake_robot of its own, passing
    through the others.
    """
    return experiment.radius > 0 or experiment.avoidance.on or engine == 'mujoco'


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
            'blur': float(fake.blur), 'brightness': float(fake.brightness),
            # an empty list has no type in a parameters file: the ideal lens is the default
            **({'distortion': [float(v) for v in fake.distortion]} if fake.distortion else {}),
            **overrides}))
    return launches


CONTROLLER_GROUP = 'controllers_'   # the key of a process of grouped controllers, + agents
NODE_GROUP = 'curve_formation.nodes.node_group'


@dataclass(frozen=True)
class GroupLaunch:
    """Controllers that share one process (nodes.node_group): key controllers_<first>-<last>
    and their launches; the group file params/<key>.group.yaml lists them.
    """

    key: str
    launches: tuple

    @property
    def file_name(self):
        return f'{self.key}.group.yaml'


def grouped(launches, size):
    """The launches in their order with the controllers in groups of `size` (a GroupLaunch
    where each group's first controller was); unchanged for size 1.
    """
    if size <= 1:
        return list(launches)
    controllers = [launch for launch in launches if part_of(launch.module) == 'controllers']
    grouped_keys = {launch.key for launch in controllers}
    groups = {}   # the key of each group's first controller -> the group
    for first in range(0, len(controllers), size):
        chunk = tuple(controllers[first:first + size])
        groups[chunk[0].key] = GroupLaunch(
            f'{CONTROLLER_GROUP}{chunk[0].agent}-{chunk[-1].agent}', chunk)
    return [groups.get(launch.key, launch) for launch in launches
            if launch.key in groups or launch.key not in grouped_keys]


def write_group_file(group, folder):
    """folder/<key>.group.yaml: the group's nodes for nodes.node_group, each with its
    parameters file (beside it in folder); returns its path.
    """
    path = Path(folder) / group.file_name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump([
        {'module': launch.program, 'class': node_class(launch.program).__name__,
         'namespace': launch.namespace, 'params_file': f'{launch.key}.yaml'}
        for launch in group.launches], sort_keys=False))
    return path


def write_params_files(launches, folder):
    """One ROS 2 parameters file per node, `<key>.yaml`; returns {key: path}. Each is keyed
    `/**/<node name>`: it applies to that node under whatever namespace it is started in
    (`-r __ns:=/mona_3`), and to no other node.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = {}
    for launch in launches:
        path = folder / f'{launch.key}.yaml'
        path.write_text(yaml.safe_dump({f'/**/{launch.name}': {
            'ros__parameters': launch.parameters}}, sort_keys=False))
        paths[launch.key] = path
    return paths


# Each node module: the class its console script runs (to start it in the runner's own
# process) and the part of the graph (run_options.PARTS) it belongs to. Its console script
# is named as its node (the module's NODE_NAME).
NODES = {'curve_formation.nodes.curve_server': ('CurveServer', 'curve_server'),
         'curve_formation.nodes.formation_controller': ('FormationController', 'controllers'),
         'curve_formation.nodes.robot_bridge': ('RobotBridge', 'robots'),
         'curve_formation.nodes.fake_robot': ('FakeRobot', 'robots'),
         'curve_formation.nodes.fake_arena': ('FakeArena', 'robots'),
         'curve_formation.nodes.camera_tracker': ('CameraTracker', 'camera'),
         'curve_formation.nodes.fake_camera': ('FakeCamera', 'camera')}


def part_of(module):
    """The part of the graph (run_options.PARTS) a node module belongs to."""
    return NODES[module][1]


def executable(module):
    """The console script (`ros2 run curve_formation <it>`) of a node module."""
    return importlib.import_module(module).NODE_NAME


def node_class(module):
    """The Node subclass a node module's console script runs: the package's (NODES), or a
    variant module's NODE_CLASS.
    """
    loaded = importlib.import_module(module)
    return getattr(loaded, NODES[module][0]) if module in NODES else loaded.NODE_CLASS


def held_robots(key):
    """The robots whose nodes a node process held, by its key: [3] for robot_3.<node>,
    [5, 6, 7, 8] for a group of controllers controllers_5-8, [] for the team's nodes.
    """
    if key.startswith(CONTROLLER_GROUP):
        first, _, last = key[len(CONTROLLER_GROUP):].partition('-')
        return list(range(int(first), int(last) + 1))
    robot = robot_index(key)
    return [] if robot is None else [robot]
