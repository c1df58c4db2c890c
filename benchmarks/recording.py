"""Recording throughput: what the bag recorder sustains, and whether it loses anything.

Run: scripts/bench recording   (--duration S, --no-images, --resolution W H)

A publisher process sends, with the nodes' own QoS, 9 robots' topics (pose at 30 Hz; cmd_vel,
formation_state and disturbance_estimate at 10 Hz) plus mono8 camera frames (1280x720 by
default) at 30 Hz, numbering what it sends. This process records them with the runner's
Recorder into an MCAP bag and then a sqlite3 one (--storage), reads each back and prints, per
kind of topic, published vs recorded, and the sustained messages/s and MB/s. Lost = published
- recorded: on a reliable topic that is the recorder's loss; on a best-effort topic (poses,
images) it can also be DDS dropping a sample the recorder was too busy to take.
Both processes use curve_formation/fastdds_large_data.xml (shared memory with large
segments), as every process of a run does; --dds-defaults shows what Fast DDS's defaults do.
"""

import argparse
import json
import os
from pathlib import Path
import shutil
import subprocess
import sys
import tempfile
import time

from curve_formation.paths import DDS_PROFILE_ENV, use_dds_profile


PUBLISHER = r"""
import json, os, sys, time
import numpy as np
import rclpy
from geometry_msgs.msg import PoseStamped, Twist, Vector3Stamped
from sensor_msgs.msg import Image, JointState
from curve_formation.core.controller.inputs import State
from curve_formation.nodes import messages, qos, topics
duration, width, height = float(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3])
images = sys.argv[4] == '1'
rclpy.init()
node = rclpy.create_node('load')
pubs = {}
KINDS = {'pose': (PoseStamped, topics.POSE, qos.SENSOR),
         'cmd_vel': (Twist, topics.CMD_VEL, qos.COMMAND),
         'state': (JointState, topics.STATE, qos.STATE),
         'estimate': (Vector3Stamped, topics.ESTIMATE, qos.STATE)}
for i in range(1, 10):
    for kind, (cls, name, profile) in KINDS.items():
        pubs[(i, kind)] = node.create_publisher(cls, topics.robot_topic(i, name), profile)
if images:
    pubs[(0, 'image')] = node.create_publisher(Image, topics.CAMERA_IMAGE, qos.IMAGE)
deadline = time.monotonic() + 30
while any(p.get_subscription_count() == 0 for p in pubs.values()):
    rclpy.spin_once(node, timeout_sec=0.05)
    if time.monotonic() > deadline:
        sys.exit('the recorder never subscribed')
frame = np.random.default_rng(0).integers(0, 256, (height, width), dtype=np.uint8)
sent = {k: 0 for k in pubs}
start = time.monotonic()
tick = 0
while time.monotonic() - start < duration:
    now = time.time()
    for i in range(1, 10):
        pubs[(i, 'pose')].publish(messages.pose_to_msg(i, tick, 0.0, now))
        sent[(i, 'pose')] += 1
        if tick % 3 == 0:
            pubs[(i, 'cmd_vel')].publish(messages.twist_to_msg(0.01, tick))
            pubs[(i, 'state')].publish(messages.state_to_msg(State((0.1, 0.2), 0, now, 0.0)))
            pubs[(i, 'estimate')].publish(messages.estimate_to_msg((0.0, tick), now))
            for k in ('cmd_vel', 'state', 'estimate'):
                sent[(i, k)] += 1
    if images:
        pubs[(0, 'image')].publish(messages.image_to_msg(frame, now))
        sent[(0, 'image')] += 1
    tick += 1
    time.sleep(max(0.0, start + tick / 30.0 - time.monotonic()))
time.sleep(1.0)   # let reliable messages drain
totals = {}
for (i, kind), count in sent.items():
    totals[kind] = totals.get(kind, 0) + count
print(json.dumps(totals))
node.destroy_node()
rclpy.shutdown()
"""


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--duration', type=float, default=30.0)
    parser.add_argument('--resolution', type=int, nargs=2, default=(1280, 720))
    parser.add_argument('--no-images', action='store_true')
    parser.add_argument('--storage', choices=('mcap', 'sqlite3', 'both'), default='both',
                        help='bag storage to measure (default: both, side by side)')
    parser.add_argument('--dds-defaults', action='store_true',
                        help="Fast DDS's default transports instead of our profile")
    args = parser.parse_args()
    if args.dds_defaults:
        os.environ.pop(DDS_PROFILE_ENV, None)
    else:
        use_dds_profile(large_data=True)
    os.environ.setdefault('ROS_DOMAIN_ID', '96')
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    images = not args.no_images
    storages = ('mcap', 'sqlite3') if args.storage == 'both' else (args.storage,)
    print(('Fast DDS defaults; ' if args.dds_defaults else 'our Fast DDS profile; ')
          + f'{args.duration:g} s, 9 robots (pose 30 Hz; cmd_vel, state, estimate 10 Hz)'
          + (f' + {args.resolution[0]}x{args.resolution[1]} mono8 at 30 Hz' if images else ''))
    results = {storage: measure(storage, args.duration, args.resolution, images)
               for storage in storages}
    print(f'{"":>10s} ' + ' '.join(f'{s + " published / recorded / lost":>36s}'
                                   for s in storages))
    for kind in results[storages[0]]['sent']:
        print(f'{kind:>10s} ' + ' '.join(
            f'{r["sent"][kind]:>18d} / {r["recorded"].get(kind, 0):>6d} / '
            f'{r["sent"][kind] - r["recorded"].get(kind, 0):>6d}' for r in results.values()))
    for storage, r in results.items():
        print(f'{storage:>8s}: {r["messages"] / r["wall"]:.0f} messages/s, '
              f'{r["size"] / r["wall"] / 1e6:.1f} MB/s to disk ({r["size"] / 1e6:.0f} MB); '
              f'recorder CPU {100 * r["cpu"] / r["wall"]:.0f} % of a core')


def measure(storage, duration, resolution, images):
    """Record the publisher's load into a new bag of `storage`; what was sent and recorded."""
    import rclpy
    from rclpy.context import Context

    from curve_formation.bags.bag import bag_summary, BagWriter
    from curve_formation.nodes import topics
    from curve_formation.nodes.recorder import Recorder
    from curve_formation.nodes.runtime import make_executor

    folder = Path(tempfile.mkdtemp(prefix='recording-bench-'))
    path = folder / 'bag'
    context = Context()
    rclpy.init(context=context)
    executor = make_executor(context)   # as the runner hosts the recorder
    topic_list = topics.recorded(9) + ([topics.REGISTRY[topics.CAMERA_IMAGE]]
                                       if images else [])
    publisher = subprocess.Popen(
        [sys.executable, '-c', PUBLISHER, str(duration), str(resolution[0]),
         str(resolution[1]), '1' if images else '0'], stdout=subprocess.PIPE, text=True)
    with BagWriter(path, storage) as writer:
        recorder = Recorder(writer, topic_list, context=context)
        executor.add_node(recorder)
        started = time.monotonic()
        cpu = time.process_time()
        while publisher.poll() is None:
            executor.spin_once(timeout_sec=0.05)
        end = time.monotonic() + 1.0
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.05)
        wall = time.monotonic() - started
        cpu = time.process_time() - cpu
    executor.shutdown()
    recorder.destroy_node()
    rclpy.try_shutdown(context=context)
    sent = json.loads(publisher.stdout.read().strip().splitlines()[-1])
    recorded = {}
    for topic, (_, count) in bag_summary(path).items():
        kind = ('image' if topic == topics.CAMERA_IMAGE else
                {'pose': 'pose', 'cmd_vel': 'cmd_vel', 'formation_state': 'state',
                 'disturbance_estimate': 'estimate'}.get(topic.rsplit('/', 1)[-1]))
        if kind:
            recorded[kind] = recorded.get(kind, 0) + count
    size = sum(f.stat().st_size for f in path.iterdir())
    shutil.rmtree(folder)
    return {'sent': sent, 'recorded': recorded, 'messages': sum(recorded.values()),
            'size': size, 'wall': wall, 'cpu': cpu}


if __name__ == '__main__':
    main()
