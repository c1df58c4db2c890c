"""The curve message (std_msgs/Float64MultiArray) the curve server sends: coefficients,
each agent's parameter, the curve's rate and clock, converted both ways without DDS.
"""

import numpy as np
import pytest

from curve_formation.core.config.loading import load_experiment
from curve_formation.core.formation.curve_codec import CurveClock
from curve_formation.core.formation.motion import CurveMotion
from curve_formation.nodes import messages
from curve_formation.paths import resolve_config


def test_curve_message_round_trip_with_and_without_agent_parameters():
    curve = load_experiment(resolve_config('closed_curve')).phases[0].curve
    msg = messages.curve_to_msg(curve, 4, [0.5, 0.0, 0.25])
    back, curve_id = messages.curve_from_msg(msg)
    np.testing.assert_allclose(back.xi, curve.xi)
    assert curve_id == 4
    np.testing.assert_allclose(messages.agent_parameters_from_msg(msg), [0.5, 0.0, 0.25])
    assert messages.agent_parameters_from_msg(messages.curve_to_msg(curve, 4)) is None
    msg.layout.dim[-1].size = 99
    with pytest.raises(messages.MessageError, match='99 agent parameters'):
        messages.agent_parameters_from_msg(msg)


def test_a_moving_curve_message_carries_its_rate_and_clock():
    curve = load_experiment(resolve_config('closed_curve')).phases[0].curve
    rate = CurveMotion((0.01, 0.0)).rate(curve, 0.0)
    msg = messages.curve_to_msg(curve, 2, [0.5, 0.0, 0.25], rate,
                                CurveClock(1.7e9 + 0.123456, 3.5))
    back, _ = messages.curve_from_msg(msg)
    np.testing.assert_allclose(back.xi, curve.xi)
    np.testing.assert_allclose(messages.curve_rate_from_msg(msg).xi, rate.xi)
    clock = messages.curve_clock_from_msg(msg)
    assert clock.valid_at == 1.7e9 + 0.123456 and clock.moving_for == 3.5
    assert clock.motion_began == pytest.approx(1.7e9 - 3.376544, abs=1e-6)
    assert clock.run_time is None and clock.run_start is None
    dated = messages.curve_clock_from_msg(messages.curve_to_msg(
        curve, 2, [0.5, 0.0, 0.25], rate, CurveClock(1.7e9, 3.5, 62.0)))
    assert dated == CurveClock(1.7e9, 3.5, 62.0) and dated.run_start == 1.7e9 - 62.0
    np.testing.assert_allclose(messages.agent_parameters_from_msg(msg), [0.5, 0.0, 0.25])
    assert messages.curve_clock_from_msg(messages.curve_to_msg(curve, 2)) is None
    backwards = messages.curve_to_msg(curve, 2, None, rate, CurveClock(5.0, -1.0))
    with pytest.raises(messages.MessageError, match='moved for -1 s'):
        messages.curve_clock_from_msg(backwards)
