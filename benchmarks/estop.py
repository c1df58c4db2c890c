"""How fast `curve-formation estop on` stops every robot of the arena demo.

Run: scripts/bench estop [--tries 20] [--modes processes single]

For each mode (run's default: a process per node, the controllers grouped by core; or every
node in one process), one run of the arena
demo (9 robots, fake arena); `tries` times: `estop on` is started as a user starts it (a new
Python process), then `estop off` once it has exited. Printed per mode, median and max over
the tries, in seconds:
- start -> last zero: from starting the command to the DDS source time of the last robot's
  first zero cmd_vel (the goal's figure: what the operator waits for);
- first -> last zero: from the first robot's zero command to the last one's (how together the
  robots stop; the tests hold it within 2 control periods);
- command ends: from starting the command to its exit, confirmations gathered.
"""

import argparse
import os
from pathlib import Path
import random
import statistics
import subprocess
import sys
import tempfile
import time

from geometry_msgs.msg import Twist
from rclpy.node import Node

from curve_formation.nodes import qos, topics
from curve_formation.nodes.runtime import WithMessageInfo
from curve_formation.paths import resolve_config
from curve_formation.run.run_options import RunOptions
from curve_formation.run.runner import Run


ROBOTS = 9


def cli(run, state):
    """Start `curve-formation estop STATE` and spin the run until it ends; (start, end) s."""
    started = time.time()
    proc = subprocess.Popen([sys.executable, '-m', 'curve_formation.cli', 'estop', state],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    run.spin_until(lambda: proc.poll() is not None, 60.0, 'the estop command')
    out, err = proc.communicate()
    if proc.returncode != 0:
        raise SystemExit(f'estop {state} failed: {out}{err}')
    return started, time.time()


def measure(single, tries, folder):
    zero_times = {i: [] for i in range(1, ROBOTS + 1)}   # DDS source times of zero commands
    options = RunOptions(single_process=single, isolated=True)
    rows = []
    with Run(resolve_config('arena_demo'), folder, options, log=lambda *_: None) as run:
        node = Node('estop_bench', context=run.observers.context)
        for i in zero_times:
            node.create_subscription(
                Twist, topics.robot_topic(i, topics.CMD_VEL),
                WithMessageInfo(lambda m, info, i=i: zero_times[i].append(
                    info['source_timestamp'] * 1e-9) if m.linear.x == m.angular.z == 0.0
                    else None), qos.COMMAND)
        run.observers.add_node(node)
        run.spin_for(3.0)
        for _ in range(tries):
            started, ended = cli(run, 'on')
            run.spin_for(0.3)
            firsts = [min(t for t in times if t >= started) for times in zero_times.values()]
            rows.append((max(firsts) - started, max(firsts) - min(firsts), ended - started))
            cli(run, 'off')
            run.spin_for(1.0)
    return rows


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--tries', type=int, default=20)
    parser.add_argument('--modes', nargs='+', choices=('processes', 'single'),
                        default=['processes', 'single'])
    args = parser.parse_args()
    os.environ.setdefault('ROS_DOMAIN_ID', str(random.SystemRandom().randint(1, 101)))
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    print(f'arena demo, {ROBOTS} robots, {args.tries} tries per mode; seconds, median / max')
    print(f'{"mode":>22} | {"start -> last zero":>18} | {"first -> last zero":>18} | '
          f'{"command ends":>14}')
    for mode in args.modes:
        with tempfile.TemporaryDirectory() as folder:
            rows = measure(mode == 'single', args.tries, Path(folder))
        columns = zip(*rows, strict=True)
        cells = [f'{statistics.median(col):.3f} / {max(col):.3f}' for col in columns]
        name = 'one process per node' if mode == 'processes' else 'single process'
        print(f'{name:>22} | {cells[0]:>18} | {cells[1]:>18} | {cells[2]:>14}', flush=True)


if __name__ == '__main__':
    main()
