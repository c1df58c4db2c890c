"""`curve-formation`: simulate, run, record and analyse formation experiments.

Subcommands: check, sim (batch simulator), demo (the headless main job), run (ROS 2 node
graph), params (its parameters files and `ros2 run` start scripts), preflight (the robots
behind their links), analyze, replay and bag (info, repair) for recorded bags, measure-link,
estop, calibrate-camera (the lens, from ChArUco board views), discovery-server, clean-shm,
nodes-doc.
Bad input ends with one line `error: FILE: KEY: ...` and exit status 2, never a traceback.
"""

import argparse
import math
import os
import sys

from curve_formation import commands
from curve_formation.bags.bag import BagError, DEFAULT_STORAGE, STORAGES
from curve_formation.core.config.errors import ConfigError
from curve_formation.core.config.marker_ids import MARKER_IDS
from curve_formation.core.controller.settings import SETTINGS
from curve_formation.paths import use_dds_profile
from curve_formation.results.provenance import command_line
from curve_formation.scheduling import CONTROLLERS, priority_problem


def _allow_missing_option(parser, then):
    """--allow-missing: robots that may fail the pre-flight; `then`: what follows."""
    parser.add_argument('--allow-missing', metavar='LIST',
                        help=f'robots (e.g. 4,7) that may fail the pre-flight{then}')


def _animate_option(parser):
    parser.add_argument('--animate', action='store_true',
                        help='also write animation.mp4 of the run (robots, targets, curve)')


class _Parser(argparse.ArgumentParser):
    """argparse, with a misuse reported as one `error:` line (exit status 2)."""

    def error(self, message):
        self.exit(2, f'error: {self.prog}: {message} (see {self.prog} --help)\n')


def _finite_number(text):
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected a number, got {text!r}') from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f'expected a finite number, got {text!r}')
    return value


def positive(text):
    """argparse type: a finite number > 0."""
    value = _finite_number(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f'expected a number > 0, got {text!r}')
    return value


def not_negative(text):
    """argparse type: a finite number >= 0."""
    value = _finite_number(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f'expected a number >= 0, got {text!r}')
    return value


def _realtime_option(parser):
    parser.add_argument('--realtime-priority', type=_priority, default=CONTROLLERS, metavar='P',
                        help="the controllers' processes take SCHED_FIFO priority P (1-99) so "
                        'that a busy PC cannot delay their ticks (needs root, CAP_SYS_NICE or '
                        'an rtprio limit; else a note in their logs and normal scheduling); '
                        f'0: normal scheduling; default {CONTROLLERS} (docs/performance.md)')


def _priority(text):
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected an integer, got {text!r}') from None
    problem = priority_problem(value)
    if problem:
        raise argparse.ArgumentTypeError(problem)
    return value


def _at_least_one(text):
    """argparse type: an integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f'expected an integer >= 1, got {text!r}')
    return value


def _physics_option(parser, what):
    """--physics: the world the simulated robots live in (default: physics.engine)."""
    from curve_formation.core.world.worlds import ENGINES
    parser.add_argument('--physics', choices=ENGINES,
                        help=f"{what}; default: the experiment's physics.engine (kinematic)")


def _force_option(parser):
    parser.add_argument('--force', action='store_true',
                        help='write into a non-empty --out (its files are replaced)')


def build_parser():
    from curve_formation import version
    parser = _Parser(prog='curve-formation', description=__doc__.split('\n')[0])
    parser.add_argument('--version', action='version', version=f'%(prog)s {version()}')
    sub = parser.add_subparsers(dest='command', required=True, parser_class=_Parser)
    check = sub.add_parser('check', help='validate an experiment and report what was checked')
    check.add_argument('config', help='experiment YAML path or shipped name')
    check.add_argument('--json', action='store_true', help='print the report as JSON')
    check.set_defaults(func=commands.cmd_check)
    sim = sub.add_parser('sim', help='batch-simulate an experiment')
    sim.add_argument('config', help='experiment YAML path or shipped name (e.g. closed_curve)')
    sim.add_argument('--out', required=True, help='output folder')
    sim.add_argument('--law', choices=SETTINGS['controller.law'].choices,
                     help="override controller.law (paper: the paper's reference law)")
    sim.add_argument('--heading', choices=SETTINGS['controller.heading'].choices,
                     help='override controller.heading')
    mode = sim.add_mutually_exclusive_group()
    mode.add_argument('--rate', type=positive, help='zero-order-hold control rate (Hz)')
    mode.add_argument('--continuous', action='store_true', help='continuous control')
    _physics_option(sim, "kinematic: the batch simulator (exact, fast); mujoco: the nodes' "
                    'tick pipeline with the robots as MuJoCo bodies')
    _animate_option(sim)
    _force_option(sim)
    sim.set_defaults(func=commands.cmd_sim)
    run = sub.add_parser('run', help='run the experiment as a ROS 2 node graph')
    run.add_argument('config', help='experiment YAML path or shipped name')
    run.add_argument('--out', default='out/run', help='output folder')
    run.add_argument('--duration', type=positive, help="seconds to run (default: the file's)")
    run.add_argument('--rate', type=positive, help="control rate (Hz; default: the file's or 10)")
    run.add_argument('--single-process', action='store_true',
                     help='all nodes in one process and executor')
    run.add_argument('--controllers-per-process', type=_at_least_one, metavar='K',
                     help='K controllers share each process (one context and executor, as a '
                     'component container): a team of N needs about N/K DDS participants; '
                     'default one group per core of this PC (1 where the team has no more '
                     'robots than cores), at most 25 controllers and 13 groups; 1: a process '
                     'each, a crash stops one robot')
    _realtime_option(run)
    run.add_argument('--bag', help='record a ROS 2 bag at this new path')
    _animate_option(run)
    run.add_argument('--bag-storage', choices=tuple(STORAGES), default=DEFAULT_STORAGE,
                     help="bag storage (default mcap, as Jazzy's ros2 bag record)")
    run.add_argument('--no-sim', action='store_true',
                     help='no fake robots: drive the real robots that publish /robot_<i>/pose')
    run.add_argument('--camera', action='store_true',
                     help='poses from camera_tracker (the experiment needs `camera`): fed by '
                     'fake_camera rendering the fake robots, or with --no-sim by a real camera '
                     'driver on /camera/image_raw')
    run.add_argument('--bridge', choices=('udp', 'pty'),
                     help='the real path to a robot: each cmd_vel through a robot_bridge, as '
                     "wheel speeds in the robot's wire format, over UDP or a serial line (a "
                     'pseudo-terminal) to emulated Mona robots (fake_arena)')
    run.add_argument('--bag-images', action='store_true',
                     help='with --bag and --camera: record the camera frames as well (about '
                     '27 MB/s at 1280x720 and 30 Hz)')
    run.add_argument('--discovery-server', metavar='HOST:PORT',
                     help='discover through this Fast DDS discovery server (sets '
                     'ROS_DISCOVERY_SERVER; for networks where multicast fails, '
                     'docs/arena-setup.md)')
    run.add_argument('--isolated', action='store_true',
                     help='a private random ROS_DOMAIN_ID and LOCALHOST discovery (tests, '
                     "demos); default: the caller's ROS_DOMAIN_ID (0 when unset) and discovery "
                     'range, where RViz and the robot drivers are')
    run.add_argument('--only', metavar='PARTS',
                     help='run only these parts of the graph on this host, comma-separated: '
                     'curve_server, controllers, robots, camera, observer (one command per '
                     'host, same ROS_DOMAIN_ID; docs/arena-setup.md)')
    run.add_argument('--agents', metavar='LIST',
                     help="with --only: run only these agents' controllers and robots here, "
                     'e.g. 1-5,9 (a team spread over several hosts)')
    _allow_missing_option(run, ': the run goes on without those that do, the others '
                          'renumbered 1.. in order (the graph must stay rooted at the '
                          "leader); metrics.json's preflight says who")
    run.add_argument('--no-preflight', action='store_true',
                     help='skip the pre-flight of the robots behind links (robots.fleet, or '
                     '--bridge): marker seen, link answering, stop confirmed')
    _physics_option(run, "the fake robots' world (fake_arena)")
    _force_option(run)
    run.set_defaults(func=commands.cmd_run)
    params = sub.add_parser('params', help="write each node's ROS 2 parameters file and "
                            'the `ros2 run` start scripts of the graph, starting nothing')
    params.add_argument('config', help='experiment YAML path or shipped name')
    params.add_argument('--out', required=True, help='folder for params/ and start_*.sh')
    params.add_argument('--rate', type=positive, help="control rate (Hz; default: the file's)")
    params.add_argument('--no-sim', action='store_true',
                        help='no fake robots (real robots publish /robot_<i>/pose)')
    params.add_argument('--camera', action='store_true', help='poses from camera_tracker')
    params.add_argument('--controllers-per-process', type=_at_least_one, metavar='K',
                        help='K controllers share each process (see run)')
    _realtime_option(params)
    params.add_argument('--bridge', choices=('udp', 'pty'),
                        help='each cmd_vel through a robot_bridge (see run --bridge)')
    params.add_argument('--observer', action='store_true',
                        help='also start_observer.sh: `curve-formation run --only observer` '
                        'measures the run (metrics, figures); the curve server waits for it')
    params.add_argument('--bag', help='with the observer, record a bag at this new path')
    _physics_option(params, "the fake robots' world (fake_arena)")
    _force_option(params)
    params.set_defaults(func=commands.cmd_params)
    analyze = sub.add_parser('analyze', help='metrics and figures from a recorded bag')
    analyze.add_argument('bag', help='bag folder')
    analyze.add_argument('--out', required=True, help='output folder')
    analyze.add_argument('--experiment', help='experiment YAML, if the bag does not carry it')
    analyze.add_argument('--compare', help='a second run to overlay: a bag, or a folder of sim, '
                         'run or analyze (e.g. real vs simulated, before vs after)')
    _animate_option(analyze)
    analyze.add_argument('--compare-sim', action='store_true',
                         help="overlay the batch simulator run from the bag's own start and "
                         'curves: paths, error norms, settling per phase')
    _force_option(analyze)
    analyze.set_defaults(func=commands.cmd_analyze)
    animate = sub.add_parser('animate', help='an animation (MP4 or GIF) of a run folder or bag')
    animate.add_argument('source', help='a run folder (sim, run, analyze --out) or a bag')
    animate.add_argument('--out', required=True, help='the film: FILE.mp4 or FILE.gif')
    animate.add_argument('--experiment', help='experiment YAML, if the source does not carry it')
    animate.add_argument('--fps', type=positive, default=15.0, help='frames per second of film')
    animate.add_argument('--max-seconds', type=positive, default=30.0,
                         help='longest film (s): a longer run is played faster')
    animate.add_argument('--camera', action='store_true',
                         help="beside the plan, the overhead camera's view (rendered; needs "
                              "the experiment's camera and arena)")
    _force_option(animate)
    animate.set_defaults(func=commands.cmd_animate)
    link = sub.add_parser('measure-link', help="each robot's command latency and motors' lag "
                          'from a recorded bag (its cmd_vel against its poses), and the '
                          'experiment settings')
    link.add_argument('bag', help='bag folder of a run in which the robots drive')
    link.add_argument('--json', help='also write the figures to this JSON file')
    link.add_argument('--motor-time-constant', type=float, metavar='S',
                      help="the motors' first-order lag (s) the commands act through, not "
                           "to be read as latency (default: the bag's experiment's "
                           'limits.motor_time_constant, else estimated with the latency)')
    link.set_defaults(func=commands.cmd_measure_link)
    bag = sub.add_parser('bag', help='inspect or repair a bag (no ROS CLI needed)')
    bag_sub = bag.add_subparsers(dest='bag_command', required=True, parser_class=_Parser)
    info = bag_sub.add_parser('info', help='what `ros2 bag info` prints: storage, duration, '
                              'topics with types, counts and QoS')
    info.add_argument('bag', help='bag folder')
    info.add_argument('--json', action='store_true', help='print it as JSON')
    info.set_defaults(func=commands.cmd_bag_info)
    fix = bag_sub.add_parser('repair', help='rewrite the bag of a run killed hard (no '
                             'metadata.yaml, MCAP without summary) as a complete bag')
    fix.add_argument('bag', help='bag folder')
    fix.add_argument('--out', help='folder of the repaired bag (default BAG-repaired)')
    fix.set_defaults(func=commands.cmd_bag_repair)
    rep = sub.add_parser('replay', help='publish a bag with its original timing and types')
    rep.add_argument('bag', help='bag folder')
    rep.add_argument('--rate', type=positive, default=1.0, help='speed factor (2 = twice as fast)')
    rep.add_argument('--topics', nargs='+', help='only these topics')
    rep.add_argument('--loop', action='store_true', help='start again at the end')
    rep.add_argument('--start', type=not_negative, default=0.0, help='skip this many seconds')
    rep.add_argument('--no-clock', action='store_true', help='do not publish /clock')
    rep.add_argument('--wait', type=not_negative, default=5.0,
                     help='seconds to wait for subscribers before starting')
    rep.set_defaults(func=commands.cmd_replay)
    estop = sub.add_parser('estop', help='engage (on) or release (off) the e-stop of every '
                           'robot on this ROS_DOMAIN_ID; exits 0 once every robot confirmed '
                           'it, 1 naming those that did not')
    estop.add_argument('state', choices=['on', 'off'])
    expected = estop.add_mutually_exclusive_group()
    expected.add_argument('--expect', type=_at_least_one, metavar='N',
                          help='robots to expect (default: as many as the controllers on the '
                          'domain say the formation has)')
    expected.add_argument('--experiment', metavar='FILE',
                          help='expect the robots of this experiment')
    estop.add_argument('--wait', type=not_negative, default=10.0,
                       help='seconds to wait for every robot to confirm (default 10: DDS '
                       'discovers a formation of 9 robots and its other nodes in 2-5 s)')
    estop.add_argument('--hold', action='store_true',
                       help='once confirmed, keep sending it every second until Ctrl-C (each '
                       'node holds it anyway)')
    estop.set_defaults(func=commands.cmd_estop)
    pre = sub.add_parser('preflight', help="check every robot of the file's robots.fleet "
                         'before a run: marker seen, link answering, stop confirmed; exit 2 '
                         'naming each robot that fails (run it before the robot bridges start)')
    pre.add_argument('config', help='experiment YAML path or shipped name')
    _allow_missing_option(pre, ' and the pre-flight still passes')
    pre.add_argument('--json', metavar='FILE', help='also write the result as JSON')
    pre.set_defaults(func=commands.cmd_preflight)
    server = sub.add_parser('discovery-server', help='run a Fast DDS discovery server (for '
                            'networks where multicast fails; runs use it with '
                            '--discovery-server HOST:PORT)')
    server.add_argument('--address', default='127.0.0.1',
                        help="this PC's address the robots' PCs reach it at")
    server.add_argument('--port', type=int, default=11811)
    server.set_defaults(func=commands.cmd_discovery_server)
    shm = sub.add_parser('clean-shm', help="remove Fast DDS's shared-memory files that "
                         'processes killed hard left in /dev/shm (files in use are kept)')
    shm.set_defaults(func=commands.cmd_clean_shm)
    calib = sub.add_parser('calibrate-camera', help="the camera's lens (intrinsics) from "
                           'views of a ChArUco board, written for camera.intrinsics_file')
    calib.add_argument('source', help='a folder of images, a video file or a device number')
    calib.add_argument('--out', required=True, help='intrinsics file to write (YAML)')
    calib.add_argument('--squares', type=int, nargs=2, default=(7, 5),
                       metavar=('COLUMNS', 'ROWS'), help='board squares (default 7 5)')
    calib.add_argument('--square-size', type=positive, default=0.04,
                       help='side of a square as printed (m, default 0.04)')
    calib.add_argument('--marker-size', type=positive, default=0.03,
                       help='side of a marker as printed (m, default 0.03)')
    calib.add_argument('--dictionary', default='DICT_5X5_100', choices=sorted(MARKER_IDS),
                       metavar='NAME', help='cv2.aruco dictionary (default DICT_5X5_100)')
    calib.add_argument('--max-rms', type=positive, default=1.0,
                       help='refuse a reprojection error above this (px, default 1)')
    calib.add_argument('--min-views', type=int, default=10,
                       help='refuse fewer views that show the board (default 10)')
    calib.add_argument('--every', type=int, default=1,
                       help='from a video or device: use every N-th frame')
    calib.add_argument('--limit', type=int, help='from a video or device: at most this many '
                       'frames')
    calib.set_defaults(func=commands.cmd_calibrate_camera)
    nodes_doc = sub.add_parser('nodes-doc', help='print the node reference of docs/nodes.md '
                               '(parameters, topics, QoS) from the code')
    nodes_doc.add_argument('--settings', action='store_true', help="print instead the "
                           "controller settings' table of docs/experiments.md")
    nodes_doc.set_defaults(func=commands.cmd_nodes_doc)
    demo = sub.add_parser('demo', help='the headless demo: paper cases simulated, then a ROS '
                          'run with fake robots recorded to a bag')
    demo.add_argument('--out', default='out/demo')
    demo.add_argument('--duration', type=positive, default=90.0, help='ROS run length (s)')
    demo.set_defaults(func=commands.cmd_demo)
    return parser


# An error line is cut to this many characters: a bad input can be long, the line is not.
MAX_ERROR_LINE = 480


def main(argv=None):
    """Run one command; bad input ends in one `error:` line on stderr and exit status 2.

    Anything else unexpected also ends in one line (exit status 1), naming it a bug, unless
    CURVE_FORMATION_DEBUG is set (then the traceback).
    """
    args = build_parser().parse_args(argv)
    command_line(['curve-formation', *(sys.argv[1:] if argv is None else argv)])
    # before any ROS context exists in this process; a run recording frames receives them
    use_dds_profile(large_data=getattr(args, 'bag_images', False))
    try:
        status = args.func(args)
    except (ConfigError, BagError, ValueError) as exc:
        return _error(exc, 2)
    except OSError as exc:   # a file or folder that cannot be read or written
        where = f'{exc.filename}: ' if exc.filename else ''
        return _error(f'{where}{exc.strerror or exc}', 2)
    except KeyboardInterrupt:
        return _error('interrupted', 130)
    except Exception as exc:  # noqa: BLE001 - one line, never a traceback, for any input
        if os.environ.get('CURVE_FORMATION_DEBUG'):
            raise
        return _error(f'unexpected {type(exc).__name__}: {exc} (a bug: please report it with '
                      'the command; CURVE_FORMATION_DEBUG=1 shows the traceback)', 1)
    return status if isinstance(status, int) else 0


def _error(message, status):
    text = ' '.join(str(message).split())
    if len(text) > MAX_ERROR_LINE:
        text = text[:MAX_ERROR_LINE - 3] + '...'
    print(f'error: {text}', file=sys.stderr)
    return status



if __name__ == '__main__':
    sys.exit(main())
