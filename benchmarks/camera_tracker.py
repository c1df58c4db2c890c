"""camera_tracker throughput on one core: plain cv2.aruco vs the tracker vs the node's path.

Run: scripts/bench camera_tracker   (or --frames N)

Frames: the arena demo's layout (9 robot markers, 4 corner markers) rendered at 1280x720 and
1920x1080 with pixel noise 2 and blur 0.7, robots at random separated poses. Per frame it
times (1) cv2.aruco.ArucoDetector.detectMarkers alone with the same parameters, (2)
MarkerTracker.process (detection, homography, poses) with cv2.aruco's corners
(`corner_refinement: contour`) and (3) with each marker's pattern fitted (`pattern`, the
default), (4) the node's whole path: Image message -> numpy -> process -> 9 PoseStamped +
PoseArray published. The process is pinned to one CPU
and OpenCV to one thread. Goal: well above the 30 Hz camera rate at 1080p.
"""

import argparse
import os
import time

import cv2
import numpy as np

from curve_formation.core.config.loading import load_experiment
from curve_formation.core.config.starts import random_poses
from curve_formation.nodes import messages
from curve_formation.paths import resolve_config
from curve_formation.vision.camera import overhead_camera
from curve_formation.vision.markers import MarkerLayout
from curve_formation.vision.render import ArenaRenderer, RenderOptions
from curve_formation.vision.tracker import MarkerTracker


ARENA = (1.8, 0.8)


def frames_at(layout, resolution, count, seed=0):
    renderer = ArenaRenderer(overhead_camera(ARENA, resolution), layout, ARENA,
                             RenderOptions(noise=2.0, blur=0.7), seed=seed)
    out = []
    for frame in range(count):   # 9 robots 0.12 m apart, 0.15 m or more from the edges
        poses = random_poses(9, (0.9, 0.4), (0.75, 0.25), seed * 1000 + frame, 0.12)
        out.append(renderer.render({i + 1: tuple(p) for i, p in enumerate(poses)}))
    return out


def timed(function, items):
    """Seconds per call of function(item), after one warm-up call."""
    function(items[0])
    times = []
    for item in items:
        start = time.perf_counter()
        function(item)
        times.append(time.perf_counter() - start)
    return np.array(times)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--frames', type=int, default=60)
    args = parser.parse_args()
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    cv2.setNumThreads(1)
    os.environ.setdefault('ROS_DOMAIN_ID', '97')
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    import rclpy
    from rclpy.context import Context
    from rclpy.parameter import Parameter

    from curve_formation.nodes.camera_tracker import CameraTracker

    layout = MarkerLayout.from_spec(load_experiment(resolve_config('arena_demo')).spec.camera)
    context = Context()
    rclpy.init(context=context)
    node = CameraTracker(context=context, parameter_overrides=[
        Parameter('experiment', value='arena_demo'), Parameter('debug_rate_hz', value=0.0)])
    print(f'{"resolution":>11s} {"stage":>34s} {"fps":>7s} {"p50 ms":>7s} {"p99 ms":>7s} '
          f'{"vs plain":>8s}')
    for resolution in ((1280, 720), (1920, 1080)):
        frames = frames_at(layout, resolution, args.frames)
        tracker = MarkerTracker(layout)
        outline = MarkerTracker(layout, refinement='contour')
        detector = tracker.detector
        msgs = [messages.image_to_msg(f, 0.0) for f in frames]
        stages = (('plain cv2.aruco detectMarkers', detector.detectMarkers, frames),
                  ('MarkerTracker.process, contour', outline.process, frames),
                  ('MarkerTracker.process, pattern', tracker.process, frames),
                  ('node: Image msg -> poses published', node._on_image, msgs))
        plain = None
        for name, function, items in stages:
            t = timed(function, items)
            plain = plain or np.mean(t)
            print(f'{resolution[0]:>5d}x{resolution[1]:<5d} {name:>34s} {1 / np.mean(t):7.1f} '
                  f'{np.median(t) * 1e3:7.2f} {np.percentile(t, 99) * 1e3:7.2f} '
                  f'{np.mean(t) / plain:8.2f}')
        found = np.mean([len(tracker.process(f).poses) for f in frames])
        print(f'{"":>11s} robots found per frame: {found:.2f} of 9')
    node.destroy_node()
    rclpy.try_shutdown(context=context)


if __name__ == '__main__':
    main()
