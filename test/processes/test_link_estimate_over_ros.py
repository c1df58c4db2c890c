"""The ROS loop over a jittered link settles with its latency estimated online."""

import numpy as np
import pytest


@pytest.mark.slow
@pytest.mark.parametrize('camera', [None, {}], ids=['poses', 'camera'])
def test_the_ros_loop_over_a_jittered_link_settles_with_the_latency_estimated_online(
        ros_domain, tmp_path, camera):
    """The arena demo's ROS graph, its fake robots' commands 100 ms +- 30 ms late (uniform),
    its controllers not told but estimating the latency online (estimate_latency, from 0):
    the formation settles within 1.3x of the simulator's time with no latency (measured
    1.02x), and every controller reports (on /diagnostics, in the bag) an estimate near 100 ms.
    Also with the poses from the camera (fake_camera renders the robots, camera_tracker
    finds their markers; the poses' stamps are the frames' capture times).
    """
    import yaml

    from curve_formation.bags.bag import read_messages
    from curve_formation.core.config.loading import build_experiment
    from curve_formation.core.record.metrics import result_metrics
    from curve_formation.core.sim.batch import simulate
    from curve_formation.paths import resolve_config
    from curve_formation.run.run_options import RunOptions
    from curve_formation.run.runner import Run
    data = yaml.safe_load(resolve_config('arena_demo').read_text())
    data['controller'].update(estimate_latency=True, predict_pose=True)
    path = tmp_path / 'estimated.yaml'
    path.write_text(yaml.safe_dump(data))
    with Run(path, tmp_path / 'run', RunOptions(command_latency=0.1, command_jitter=0.03,
                                                 bag_path=tmp_path / 'bag', camera=camera),
             log=lambda *_: None) as run:
        run.spin_for(40.0)
        live = run.write_results()
    plain = yaml.safe_load(resolve_config('arena_demo').read_text())
    simulated = result_metrics(simulate(build_experiment(plain, 'arena_demo.yaml'),
                                        duration=40.0))
    ros, sim = live['phases'][0], simulated['phases'][0]
    print('settling: ros', ros['settle_time'], 'simulated', sim['settle_time'])
    assert ros['settled'] and ros['settle_time'] <= 1.3 * sim['settle_time'], (ros, sim)
    latest = {}
    for _, _, _, msg in read_messages(tmp_path / 'bag', ['/diagnostics']):
        for status in msg.status:
            values = {kv.key: kv.value for kv in status.values}
            if 'command_latency' in values:
                latest[status.hardware_id] = float(values['command_latency'])
    print('estimated latencies (s):', latest)
    # DDS adds a few ms to the fake robots' 100 ms; measured 89-118 ms, median 106 ms (from
    # the camera 94-109 ms, median 103 ms; each 6 s fit standing alone: 94-123 ms)
    assert len(latest) == 9
    assert abs(np.median(list(latest.values())) - 0.1) <= 0.015, latest
    assert all(abs(v - 0.1) <= 0.025 for v in latest.values()), latest
