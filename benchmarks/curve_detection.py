"""A curve drawn on the floor: how well and how fast the camera finds it, beside the markers.

Run: scripts/bench curve_detection   (or --frames N)

Frames: drawn_curve's two lines (a closed loop, an open S) drawn 12 mm wide under its nine
robots, at 1280x720 and 1920x1080, straight down and tilted 25 degrees, pixel noise 2 and blur
0.7, the robots at their random start (the line mostly in view) and parked on their targets
(each hides 11 cm of it). Per case: the RMS distance of the curve fitted from what was found
(curve_sources.fit_points, Fourier K = 8 or polynomial p = 8, as the curve server fits it) to
the drawn line, and of the drawn line's visible points to the fit (how much of it the fit
covers); and per frame, on one core, the time of the curve search (DrawnCurveFinder.find) and
of the marker tracker (MarkerTracker.process). Goal: within 2 mm RMS; the search runs at
camera.drawn_curve.rate_hz (2 Hz by default), so it costs that many frames' worth a second.
"""

import argparse
import os
import time

import cv2
import numpy as np

from curve_formation.core.config.loading import load_experiment
from curve_formation.core.formation.curve_sources import fit_points, polyline_rms_distance
from curve_formation.core.formation.curves import make_basis
from curve_formation.paths import resolve_config
from curve_formation.vision.camera import overhead_camera
from curve_formation.vision.curve_detection import finder_for
from curve_formation.vision.markers import MarkerLayout
from curve_formation.vision.render import ArenaRenderer, FloorLine, RenderOptions
from curve_formation.vision.tracker import MarkerTracker


def case(experiment, phase, robots, tilt, resolution, frames):
    spec = experiment.spec.camera.model_copy(update={'resolution': resolution})
    layout = MarkerLayout.from_spec(spec)
    arena = tuple(experiment.spec.arena.size)
    curve = experiment.phases[phase].curve
    closed = curve.basis.closed
    _, drawn = curve.sample(1000)
    renderer = ArenaRenderer(overhead_camera(arena, resolution, tilt), layout, arena,
                             RenderOptions(2.0, 0.7), robot_radius=experiment.spec.robots.radius)
    renderer.draw_on_floor(FloorLine(drawn, closed))
    poses = {i + 1: (x, y, 0.7 * i) for i, (x, y) in enumerate(robots)}
    images = [renderer.render(poses) for _ in range(frames)]
    tracker = MarkerTracker(layout)
    finder = finder_for(tracker, spec, arena, experiment.spec.robots.radius)
    found, search, track = None, [], []
    for image in images:
        start = time.perf_counter()
        seen = tracker.process(image)
        track.append(time.perf_counter() - start)
        start = time.perf_counter()
        found = finder.find(image, [p[:2] for p in seen.poses.values()])
        search.append(time.perf_counter() - start)
    fit = fit_points(make_basis('fourier' if found.closed else 'polynomial', 8), found.points)
    _, fitted = fit.curve.sample(2000)
    visible = np.linalg.norm(drawn[:, None] - np.asarray(robots)[None], axis=2).min(axis=1) > 0.06
    return (found.closed == closed, polyline_rms_distance(fitted, drawn, closed),
            polyline_rms_distance(drawn[visible], fitted, closed), np.median(search),
            np.median(track))


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--frames', type=int, default=10)
    args = parser.parse_args()
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    cv2.setNumThreads(1)
    experiment = load_experiment(resolve_config('drawn_curve'))
    print(f'{"line":>6s} {"robots":>8s} {"tilt":>5s} {"resolution":>10s} {"found":>6s} '
          f'{"fit->line mm":>12s} {"line->fit mm":>12s} {"search ms":>9s} {"markers ms":>10s} '
          f'{"ratio":>6s}')
    worst = 0.0
    for resolution in ((1280, 720), (1920, 1080)):
        for tilt in (0.0, 25.0):
            for phase, line in ((0, 'loop'), (1, 'S')):
                for where, robots in (('start', experiment.initial_poses[:, :2]),
                                      ('on line', experiment.phases[phase].targets)):
                    ok, fit_rms, cover_rms, search, track = case(
                        experiment, phase, robots, tilt, resolution, args.frames)
                    worst = max(worst, fit_rms, cover_rms)
                    print(f'{line:>6s} {where:>8s} {tilt:5.0f} {resolution[0]:>5d}x'
                          f'{resolution[1]:<4d} {"yes" if ok else "NO":>6s} '
                          f'{1e3 * fit_rms:12.2f} {1e3 * cover_rms:12.2f} {1e3 * search:9.1f} '
                          f'{1e3 * track:10.1f} {search / track:6.1f}')
    print(f'worst RMS {1e3 * worst:.2f} mm (goal 2 mm): {"met" if worst < 0.002 else "NOT met"}')


if __name__ == '__main__':
    main()
