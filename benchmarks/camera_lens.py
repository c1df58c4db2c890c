"""The arena demo through a real-looking camera: wide-angle lens, markers above the floor,
camera tilted; calibrated and corrected, against the same run without a camera.

Run: scripts/bench camera_lens   (about 5 minutes: three 70 s ROS runs)

Steps: 20 ChArUco board views rendered through the lens are calibrated with
`curve-formation calibrate-camera`; the arena demo is then run (fake arena, fake camera
rendering lens, marker height and tilt, camera_tracker with the intrinsics file) with the
pose prediction on and off, and once without a camera. Printed per run: settling of the true
poses (s) and as a ratio to the run without camera, the tracked poses' and the laws' poses'
distance to the truth (mm RMS). Goal: settling within 1.1x, laws' poses under 0.5 mm.
"""

import argparse
import json
import os
from pathlib import Path
import tempfile

import cv2

from curve_formation.cli import main as cli
from curve_formation.paths import resolve_config
from curve_formation.vision.camera import overhead_camera
from curve_formation.vision.intrinsics import BoardSpec
from curve_formation.vision.lens import Lens
from curve_formation.vision.render import BoardRenderer, RenderOptions


LENS = [-0.3, 0.1, 0.001, -0.001]
TILT = 25.0
MARKER_HEIGHT = 0.05
RESOLUTION = (1280, 720)


def experiment_text(intrinsics, predict):
    """The arena demo with the lens, tilt and marker height, and the intrinsics file."""
    text = resolve_config('arena_demo').read_text()
    text = text.replace('  corner_size: 0.06\n', f'  corner_size: 0.06\n  marker_height: '
                        f'{MARKER_HEIGHT}\n  intrinsics_file: {intrinsics}\n')
    fake = (f'  fake: {{tilt_deg: {TILT}, height: 2.0, noise: 2.0, blur: 0.7, '
            f'distortion: {LENS}}}\n')
    lines = [fake if line.strip().startswith('fake:') else line + '\n'
             for line in text.splitlines()]
    text = ''.join(lines)
    if not predict:
        text = text.replace('predict_pose: true', 'predict_pose: false')
    return text


def run(config, out, camera):
    args = ['run', str(config), '--out', str(out), '--duration', '70', '--isolated']
    assert cli(args + (['--camera'] if camera else [])) == 0
    return json.loads((Path(out) / 'metrics.json').read_text())


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.parse_args()
    os.environ.setdefault('ROS_DOMAIN_ID', '96')
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    folder = Path(tempfile.mkdtemp(prefix='camera-lens-'))
    views = folder / 'views'
    views.mkdir()
    camera = overhead_camera((1.8, 0.8), RESOLUTION, TILT)
    boards = BoardRenderer(camera, BoardSpec(), Lens.from_coefficients(LENS),
                           RenderOptions(2.0, 0.7))
    for k, pose in enumerate(boards.random_poses(20, seed=3)):
        cv2.imwrite(str(views / f'{k:02d}.png'), boards.render(*pose))
    assert cli(['calibrate-camera', str(views), '--out', str(folder / 'lens.yaml')]) == 0
    plain = run(resolve_config('arena_demo'), folder / 'no_camera', camera=False)
    base = plain['phases'][0]['settle_time']
    print(f'\nno camera: settles in {base:.1f} s')
    print(f'{"run":>22s} {"settle (s)":>10s} {"ratio":>6s} {"tracked mm":>10s} '
          f'{"law pose mm":>11s}')
    for predict in (True, False):
        config = folder / f'lens_{predict}.yaml'
        config.write_text(experiment_text(folder / 'lens.yaml', predict))
        truth = run(config, folder / f'camera_{predict}', camera=True)['ground_truth']
        settle = truth['phases'][0]['settle_time']
        law = truth['law_pose_vs_true_position_rms']
        print(f'{"camera, prediction " + ("on" if predict else "off"):>22s} '
              f'{settle if settle else float("nan"):10.1f} '
              f'{(settle or float("nan")) / base:6.2f} '
              f'{1000 * truth["tracked_vs_true_position_rms"]:10.2f} {1000 * law:11.2f}')
    print(f'(runs in {folder})')


if __name__ == '__main__':
    main()
