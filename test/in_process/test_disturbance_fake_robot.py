"""A fake robot changes its disturbance (disturbance.varies) on the run's clock, the curve
message's.
"""

import pytest

from cases import fast_disturbed


def test_a_fake_robot_changes_its_disturbance_on_the_runs_clock(ros):
    """fake_robot with disturbance_varies (a step at 1 s, halved, on agent 1): the run's time
    comes from the curve message's clock (its run time: a message 5 s into the run puts t = 0
    5 s back), so the robot is already past the step when the curve comes.
    """
    import json
    import time

    import rclpy
    from rclpy.parameter import Parameter

    from curve_formation.core.formation.curve_codec import CurveClock
    from curve_formation.nodes import messages, topics
    from curve_formation.nodes.fake_robot import FakeRobot
    context, add, spin_until = ros
    varies = json.dumps([{'kind': 'step', 'at': 1.0, 'change': -0.5, 'agents': [1]}])
    robot = add(FakeRobot(context=context, namespace='/robot_1', parameter_overrides=[
        Parameter('index', value=1), Parameter('disturbance', value=[0.3, 0.5]),
        Parameter('disturbance_varies', value=varies)]))
    other = add(FakeRobot(context=context, namespace='/robot_2', parameter_overrides=[
        Parameter('index', value=2), Parameter('disturbance', value=[0.3, 0.5]),
        Parameter('disturbance_varies', value=varies)]))
    probe = add(rclpy.create_node('probe', context=context))
    curve_pub = topics.publisher(probe, topics.CURVE)
    phase = fast_disturbed().phases[0]
    now = time.time()
    curve_pub.publish(messages.curve_to_msg(phase.curve, 0, phase.s, None,
                                            CurveClock(now, 0.0, 5.0)))
    spin_until(lambda: robot.robot.disturbance == (0.15, 0.25))
    assert robot.run_time.start == pytest.approx(now - 5.0)
    assert other.robot.disturbance == (0.3, 0.5)   # not among the agents it acts on
    with pytest.raises(Exception, match='disturbance_varies'):   # checked as the file is
        FakeRobot(context=context, namespace='/robot_3', parameter_overrides=[
            Parameter('disturbance_varies', value='[{"kind": "sine", "amplitude": 1}]')])
