"""The link's latency measured from commands and poses (core.link_estimate, measure-link)."""

import numpy as np
import pytest

from curve_formation.core.dynamics import arc_step
from curve_formation.core.link_estimate import estimate_latency


def driven_robot(latency, jitter=0.0, loss=0.0, seed=0, seconds=30.0, drift=(0.005, 0.1),
                 noise=(0.0002, 0.003), rate=10.0, camera=30.0):
    """A Mona-like robot under wandering commands sent at `rate` Hz, each acting `latency`
    s +- a uniform `jitter` after it was sent (never before the one before it) or lost with
    probability `loss`; with a drift [d_v, d_w] while driven, seen by a camera at `camera`
    Hz with Gaussian noise (m, rad). Returns (command times, commands, pose times, poses).
    """
    rng = np.random.default_rng(seed)
    sent = np.arange(0.0, seconds, 1.0 / rate)
    v = np.clip(np.cumsum(rng.normal(0.0, 0.004, len(sent))), -0.02, 0.02)
    w = np.clip(np.cumsum(rng.normal(0.0, 0.08, len(sent))), -0.5, 0.5)
    acts = np.maximum.accumulate(sent + latency + rng.uniform(-jitter, jitter, len(sent)))
    arrive = rng.random(len(sent)) >= loss
    changes = [(a, cv, cw) for a, cv, cw, ok in zip(acts, v, w, arrive, strict=True) if ok]
    seen = np.arange(0.0, seconds, 1.0 / camera)
    pose, now, command, k, poses = (0.5, 0.4, 0.0), 0.0, (0.0, 0.0), 0, []

    def move(pose, until):
        if command == (0.0, 0.0):
            return pose
        return arc_step(*pose, command[0] + drift[0], command[1] + drift[1], until - now)

    for t in seen:
        while k < len(changes) and changes[k][0] <= t:
            pose, now = move(pose, changes[k][0]), changes[k][0]
            command, k = changes[k][1:], k + 1
        pose, now = move(pose, t), t
        poses.append(pose)
    poses = np.array(poses)
    poses[:, :2] += rng.normal(0.0, noise[0], (len(seen), 2))
    poses[:, 2] += rng.normal(0.0, noise[1], len(seen))
    return sent, np.column_stack([v, w]), seen, poses


@pytest.mark.parametrize('latency, jitter, loss', [
    (0.0, 0.0, 0.0), (0.1, 0.0, 0.0), (0.1, 0.03, 0.1), (0.25, 0.03, 0.0), (0.3, 0.0, 0.1)])
def test_the_latency_is_found_within_20_ms_under_jitter_loss_drift_and_camera_noise(
        latency, jitter, loss):
    found = estimate_latency(*driven_robot(latency, jitter, loss))
    assert found.latency == pytest.approx(latency, abs=0.02), found
    assert found.windows >= 1 and found.spread < 0.05


def test_a_robot_whose_commands_do_not_change_tells_no_latency():
    sent, commands, seen, poses = driven_robot(0.1)
    commands[:] = (0.01, 0.0)   # one steady command from start to end
    found = estimate_latency(sent, commands, seen, poses)
    assert found.latency is None and found.windows == 0


@pytest.mark.ros
def test_measure_link_finds_the_fake_robots_latency_in_a_recorded_bag(ros_domain, tmp_path):
    """The ROS graph with fake robots whose commands act 120 ms late, recorded: measure-link
    reads each robot's cmd_vel against its poses and finds 120 ms (+ DDS's few ms) within
    20 ms for every robot, and suggests that as controller.command_latency. (With +-30 ms of
    jitter, 8 s of this fast case read 114-141 ms, median 130 ms: docs/link.md.)
    """
    from conftest import DATA_DIR
    from curve_formation.cli import main
    from curve_formation.run_options import RunOptions
    from curve_formation.runner import Run
    with Run(DATA_DIR / 'fast_disturbed.yaml', tmp_path / 'run',
             RunOptions(command_latency=0.12, bag_path=tmp_path / 'bag'),
             log=lambda *_: None) as run:
        run.spin_for(8.0)
    assert main(['measure-link', str(tmp_path / 'bag'), '--json',
                 str(tmp_path / 'link.json')]) == 0
    import json
    found = json.loads((tmp_path / 'link.json').read_text())
    assert len(found['robots']) == 6
    for row in found['robots'].values():
        assert row['latency'] == pytest.approx(0.12, abs=0.02), found
    assert found['latency'] == pytest.approx(0.12, abs=0.02)
