"""Over DDS, node processes: the disturbance changes on the run's clock and the controllers
learn it.
"""

import numpy as np
import pytest
import yaml

from conftest import DATA_DIR


@pytest.mark.slow
@pytest.mark.parametrize('injected, bodies', [
    ('on_robot', False), ('on_robot', True), ('on_pc', False)])
def test_over_dds_the_disturbance_changes_on_the_runs_clock_and_the_nodes_learn_it(
        injected, bodies, ros_domain, tmp_path):
    """The ROS graph (curve server, controllers, fake robots) under a step of the disturbance
    at 4 s on agents 1-3 (halved): where it is injected (the fake robots, each its own or all
    in fake_arena's world with bodies, or the controllers on the PC), the nodes date it by
    the curve's clock, and each controller's published estimate ends on its agent's new
    value (the others on the old). The fake robots' commands act 120 ms late, as the
    controllers are told; measure-link finds that in the run's bag, for every robot.
    """
    from curve_formation.cli import main
    from curve_formation.run.run_options import RunOptions
    from curve_formation.run.runner import Run
    data = yaml.safe_load((DATA_DIR / 'fast_disturbed.yaml').read_text())
    data['disturbance'].update(injected=injected, varies=[
        {'kind': 'step', 'at': 4.0, 'change': -0.5, 'agents': [1, 2, 3]}])
    data['controller'].update(command_latency=0.12, predict_pose=True)
    if bodies:   # 5 cm discs in a 10 m spread: fake_arena, contacts unlikely
        data['robots'] = {'radius': 0.05}
    path = tmp_path / 'stepped.yaml'
    path.write_text(yaml.safe_dump(data))
    # every node in one process: the nodes and parameters of a lab's run, started sooner
    options = RunOptions(command_latency=0.12, bag_path=tmp_path / 'bag', single_process=True)
    with Run(path, tmp_path / 'run', options, log=lambda *_: None) as run:
        run.spin_for(16.0 if injected == 'on_pc' else 12.0)   # on the PC it learns slower
        recorded = run.recording()
    k2 = run.experiment.gains.k2
    learnt = recorded['dhat'][-1] * k2
    np.testing.assert_allclose(learnt[:3], [[0.15, 0.25]] * 3, atol=0.02)
    np.testing.assert_allclose(learnt[3:], [[0.3, 0.5]] * 3, atol=0.02)
    # not before its time: nearer the old value than the new just before 4 s
    before = recorded['dhat'][(recorded['t'] > 3.5) & (recorded['t'] < 3.9)] * k2
    assert len(before) and (before[:, :3, 1] > 0.375).all(), before[:, :3]
    assert main(['measure-link', str(tmp_path / 'bag'), '--json',
                 str(tmp_path / 'link.json')]) == 0
    import json
    found = json.loads((tmp_path / 'link.json').read_text())
    assert len(found['robots']) == 6
    for row in found['robots'].values():   # + DDS's few ms
        assert row['latency'] == pytest.approx(0.12, abs=0.02), found
