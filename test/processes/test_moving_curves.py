"""The shipped moving-curve experiment over DDS, and a curve that turns and one that grows:
each moving phase settles as the simulator says, and the live monitor and the bag agree.

Slow (about 2 minutes a run): `scripts/test -m slow -k moving_curves`.
"""

import pytest

from conftest import CONFIG_DIR
from curve_formation.bags.analysis import analyze_bag
from curve_formation.run.run_options import RunOptions
from curve_formation.run.runner import Run
from curve_formation.workflows import simulate_to_dir


pytestmark = pytest.mark.slow

SHIPPED = CONFIG_DIR / 'moving_curve.yaml'
MOTIONS = {
    'translates': None,   # the shipped file: 1 cm/s to the right
    'turns': '{rotation_rate: 0.01}',     # about the loop's centre, 0.4 rad by 100 s
    'grows': '{scale_rate: 0.003}',       # 1.13x by 100 s
}
RECORD_PERIOD = 1 / 20.0   # s, the monitor's and the analysis's sampling


@pytest.mark.parametrize('motion', MOTIONS)
def test_a_moving_phase_over_dds_settles_as_simulated_and_the_bag_agrees(ros_domain, tmp_path,
                                                                        motion):
    path = SHIPPED
    if MOTIONS[motion] is not None:
        text = SHIPPED.read_text()
        assert text.count('motion: {velocity: [0.01, 0.0]}') == 1
        path = tmp_path / f'moving_{motion}.yaml'
        path.write_text(text.replace('motion: {velocity: [0.01, 0.0]}',
                                     f'motion: {MOTIONS[motion]}'))
    simulated = simulate_to_dir(path, tmp_path / 'sim')
    with Run(path, tmp_path / 'run', RunOptions(bag_path=tmp_path / 'bag'),
             log=lambda *_: None) as run:
        run.spin_for(run.experiment.spec.simulation.duration)
        live = run.write_results()
    bagged = analyze_bag(tmp_path / 'bag', tmp_path / 'analysis')
    sim, ros, bag = (r['phases'][1] for r in (simulated, live, bagged))
    tolerance = ros['tolerance']
    assert ros['settled'] and bag['settled'], (ros, bag)
    print(motion, 'settling: sim', sim['settle_time'], 'ros', ros['settle_time'], 'bag',
          bag['settle_time'], 'final: ros', ros['final_error_norm'], 'bag',
          bag['final_error_norm'])
    # Within 1.2x of the simulator's time, to a sample (growth never unsettles the robots:
    # 0 s simulated). The curve server announces a curve that begins to move 0.2 s ahead,
    # so no controller's unsynchronised tick starts it late (without: the turn 2.8-3.1 s
    # against 2.24 s simulated; with: 2.17 s).
    allowed = 1.2 * sim['settle_time'] + RECORD_PERIOD
    assert ros['settle_time'] <= allowed, (ros['settle_time'], sim)
    # On its target to within 10x the tolerance's 1 % (each controller carries its moving
    # target from when the curve held, by the message's clock, not from its arrival).
    assert ros['final_error_norm'] <= 0.1 * tolerance, (ros['final_error_norm'], tolerance)
    assert abs(bag['settle_time'] - ros['settle_time']) <= 2 * RECORD_PERIOD, (bag, ros)
    assert abs(bag['final_error_norm'] - ros['final_error_norm']) <= 0.01 * tolerance
    # evenly spread on the curve where it has moved to
    assert ros['spacing']['cv'] == pytest.approx(ros['target_spacing']['cv'], abs=0.01)
