"""Experiments, curves and bags that tests in more than one tier build."""

import yaml

from conftest import CONFIG_DIR, DATA_DIR
from curve_formation.core.config.loading import build_experiment
from curve_formation.core.formation.curve_sources import expression_samples
from curve_formation.core.formation.curves import fit_curve, FourierBasis


def fast_disturbed(**disturbance):
    data = yaml.safe_load((DATA_DIR / 'fast_disturbed.yaml').read_text())
    data['disturbance'].update(disturbance)
    return build_experiment(data, 'fast_disturbed.yaml')


def circle_curve():
    s, pts = expression_samples('cos(2*pi*s)', 'sin(2*pi*s)', 100, closed=True)
    return fit_curve(FourierBasis(2), s, pts).curve


def lab_dict():
    """arena_demo with a fleet: robots 1-5 on serial radios, 6-9 on UDP, markers 11..19 (the
    camera's robot_ids left out), robot 3 with its own wheel base and motor lag.
    """
    data = yaml.safe_load((CONFIG_DIR / 'arena_demo.yaml').read_text())
    data['camera'].pop('robot_ids')
    data['robots']['fleet'] = [
        {'marker': 11 + k, 'link': f'serial:/dev/ttyUSB{k}@57600' if k < 5
         else f'udp:10.0.0.{k}:4210'} for k in range(9)]
    data['robots']['fleet'][2].update(wheel_base=0.079, motor_time_constant=0.04,
                                      format='wheel-m-s')
    return data


def tiny_bag(path, count=5, period_ms=20):
    """A bag of `count` std_msgs/Bool on /replay_test, `period_ms` apart, data alternating."""
    from rclpy.serialization import serialize_message
    from std_msgs.msg import Bool

    from curve_formation.bags.bag import BagWriter, qos
    with BagWriter(path) as writer:
        writer.add_topic('/replay_test', 'std_msgs/msg/Bool', qos(reliable=True))
        for k in range(count):
            writer.write('/replay_test', 1_000_000_000 + k * period_ms * 1_000_000,
                         serialize_message(Bool(data=k % 2 == 1)))
    return path
