"""The link's latency and the motors' lag per robot from a recorded bag: each robot's
cmd_vel (dated when the recorder got it, as the robot's link would) against its poses (dated
by their stamps, when the camera saw them), by core.controller.link_estimate. What
`curve-formation measure-link` prints, and the experiment settings it suggests
(controller.command_latency, limits.motor_time_constant).
"""

import math
from typing import Any

import numpy as np

from curve_formation.bags.bag import bag_summary, BagError, read_messages
from curve_formation.core.controller.dead_band_estimate import estimate_dead_band, NO_BAND
from curve_formation.core.controller.link_estimate import estimate_latency
from curve_formation.core.controller.motor_probe import replay_check
from curve_formation.core.controller.wheel_estimate import estimate_gains, NO_GAINS
from curve_formation.core.formation.curve_codec import CodecError
from curve_formation.interface import CMD_VEL, POSE, pose_from_msg, robot_of, twist_from_msg


# The per-robot topics the link is measured from (interface names).
MEASURED = (POSE, CMD_VEL)


def bag_experiment(path):
    """The experiment the bag carries, as parsed from its YAML ({} if none)."""
    from curve_formation.bags.analysis import EXPERIMENT_KEY
    from curve_formation.bags.bag import bag_info
    from curve_formation.core.config.loading import parse_experiment_text
    _, custom = bag_info(path)
    if EXPERIMENT_KEY not in custom:
        return {}
    data = parse_experiment_text(custom[EXPERIMENT_KEY], f'{path} (metadata)')
    return data if isinstance(data, dict) else {}


def _section(data, *keys):
    """data[keys[0]][keys[1]]..., or None where a level is missing or of another type."""
    for key in keys:
        data = data.get(key) if isinstance(data, dict) else None
    return data


def own_settings(found):
    """{agent i: {'min_wheel_speed': m/s}} from measure_bag's result: each robot's own dead
    band (its motor check's where that is used, else the band its commands told), as
    robots.fleet takes it; robots with none left out. Not the motors' lag: a robot's lag
    trades with its latency (20 ms either way on arena_demo's MuJoCo robots: docs/link.md),
    more than robots' lags differ, and the latency is told for all robots at once.
    """
    out = {}
    for i, row in found['robots'].items():
        band = _band(row)
        if band is not None:
            out[i] = {'min_wheel_speed': round(float(band), 5)}
    return out


def fleet_with_own(found):
    """The bag's experiment's robots.fleet (a list of its entries as written, agent 1
    first) with each robot's own settings (own_settings) put in; None where the experiment
    lists no fleet, or not one entry per robot measured.
    """
    fleet = found.get('fleet')
    if not isinstance(fleet, list) or not fleet or max(found['robots']) > len(fleet):
        return None
    own = own_settings(found)
    return [{**entry, **own.get(i, {})} if isinstance(entry, dict) else entry
            for i, entry in enumerate(fleet, start=1)]


def _band(row):
    """A robot's dead band (m/s) as measured: its motor check's where the check is used
    (trusted), else the band its commands told (None if neither).
    """
    check = row['check']
    if check is not None and check['used'] and check['dead_band'] is not None:
        return check['dead_band']
    return row['dead_band']


def measure_bag(path, motor_time_constant=None):
    """{'robots': {i: {'latency', 'spread', 'windows', 'residual', 'motor_time_constant',
    'wheel_gains' ([left, right] or None: core.controller.wheel_estimate, with the
    experiment's wheel base and speed), 'wheel_gain_errors', 'dead_band' (m/s of wheel
    speed or None: core.controller.dead_band_estimate) and its 'dead_band_bound' (m/s),
    'check' (where the bag holds a motor
    check, controller.motor_check: {'wheel_gains', 'dead_band' m/s or 0, 'bound' m/s,
    'repeated': stages run again},
    else None), 'commands', 'poses'}},
    'latency': the median over the robots that told one (s, or None), 'motor_time_constant':
    the motors' lag (s) the fit took the commands through (the median of the robots' where
    estimated, None if none told one), 'motor_estimated': whether it was, 'dead_band': the
    median of the robots' (each its check's where that is used), 'fleet': the bag's
    experiment's robots.fleet as written (None if it lists none)} of a bag;
    motor_time_constant None: the bag's experiment's, so that the motors' lag is not read as
    latency, or where it tells none, estimated with the latency.
    """
    experiment = bag_experiment(path)
    limits = _section(experiment, 'limits') or {}
    if motor_time_constant is None:
        motor_time_constant = float(limits.get('motor_time_constant') or 0.0) or None
    estimated = motor_time_constant is None
    wheel_base = float(limits.get('wheel_base') or 0.0)
    max_wheel_speed = float(limits.get('max_wheel_speed') or math.inf)
    topics = [t for t in bag_summary(path) if robot_of(t, MEASURED) is not None]
    commands: dict[int, list] = {}
    poses: dict[int, list] = {}
    for topic, _, stamp, msg in read_messages(path, topics):
        placed = robot_of(topic, MEASURED)
        assert placed is not None   # the topics were chosen by it
        i, kind = placed
        if kind == CMD_VEL:
            commands.setdefault(i, []).append((stamp * 1e-9, *twist_from_msg(msg)))
            continue
        try:
            x, y, theta, taken = pose_from_msg(msg)
        except CodecError:   # not a unit quaternion: as the controllers, not taken
            continue
        poses.setdefault(i, []).append((taken, x, y, theta))
    robots = sorted(set(commands) & set(poses))
    if not robots:
        raise BagError(f'{path}: no robot with both /robot_<i>/cmd_vel and /robot_<i>/pose: '
                       'nothing to time')
    out: dict[int, dict[str, Any]] = {}
    for i in robots:
        sent = np.array(commands[i])
        seen = np.array(poses[i])
        found = estimate_latency(sent[:, 0], sent[:, 1:], seen[:, 0], seen[:, 1:],
                                 motor_time_constant=motor_time_constant)
        gains, band = NO_GAINS, NO_BAND
        if found.latency is not None and found.motor_time_constant is not None:
            gains = estimate_gains(sent[:, 0], sent[:, 1:], seen[:, 0], seen[:, 1:],
                                   wheel_base, max_wheel_speed, found.latency,
                                   found.motor_time_constant)
            band = estimate_dead_band(sent[:, 0], sent[:, 1:], seen[:, 0], seen[:, 1:],
                                      wheel_base, max_wheel_speed, found.latency,
                                      found.motor_time_constant)
        check = (replay_check(sent[:, 0], sent[:, 1:], seen[:, 0], seen[:, 1:], wheel_base,
                              max_wheel_speed, float(limits.get('max_angular_rate') or math.inf))
                 if wheel_base > 0.0 and math.isfinite(max_wheel_speed) else None)
        out[i] = {'latency': found.latency, 'spread': found.spread, 'windows': found.windows,
                  'residual': found.residual, 'motor_time_constant': found.motor_time_constant,
                  'wheel_gains': None if gains.gains is None else list(gains.gains),
                  'wheel_gain_errors': None if gains.errors is None else list(gains.errors),
                  'dead_band': band.band,
                  'dead_band_bound': band.bound if band.band is not None else None,
                  'check': None if check is None or check.gains is None else {
                      'wheel_gains': list(check.gains), 'dead_band': check.band,
                      'bound': check.bound, 'repeated': check.repeated,
                      'gain_errors': (None if check.gain_errors is None
                                      else list(check.gain_errors)),
                      'used': check.trusted},
                  'commands': len(sent), 'poses': len(seen)}
    told = [r['latency'] for r in out.values() if r['latency'] is not None]
    if estimated:
        lags = [r['motor_time_constant'] for r in out.values()
                if r['motor_time_constant'] is not None]
        motor_time_constant = float(np.median(lags)) if lags else None
    bands = [b for b in (_band(r) for r in out.values()) if b]
    return {'robots': out, 'latency': float(np.median(told)) if told else None,
            'motor_time_constant': motor_time_constant, 'motor_estimated': estimated,
            'dead_band': float(np.median(bands)) if bands else None,
            'fleet': _section(experiment, 'robots', 'fleet')}
