"""What the nodes report on /diagnostics beyond their status, and how it is read: fake_arena's
contact tally, a robot bridge's link, and the runner's report of a node that died.
"""


# The hardware id under which fake_arena reports its contact tally on /diagnostics.
CONTACT_REPORTER = 'fake_arena'
# The hardware id under which the runner reports a node of the run that died (values: node,
# how), so that a bag carries it.
NODE_DEATH_REPORTER = 'node_death'


# The status name under which camera_tracker reports its camera (frames, latency, and
# calibration_rms_px: its arena calibration's residual, 'none' without one).
CAMERA_STATUS = 'camera_tracker: camera'

# The node name under which each robot_bridge reports its link on /diagnostics.
LINK_REPORTER = '/robot_bridge'
LINK_COUNTS = ('sent', 'failed', 'stops', 'replies', 'malformed', 'dropped_lines')
# The node name under which each formation_controller reports on /diagnostics, and the
# values of its report that are its robot as it holds it (core.controller.robot_model:
# RobotModel.estimates): each with `<name>_bound` and `<name>_from` beside it; numbers (s, s,
# 'left right', m/s of wheel speed) or '-' for none
CONTROLLER_REPORTER = '/formation_controller'
ESTIMATES = ('command_latency', 'motor_time_constant', 'wheel_gains', 'dead_band')


def estimate_values(estimates):
    """RobotModel.estimates() -> [(key, text)] for a controller's report: numbers as text
    (a pair space-separated), '-' for None.
    """
    def text(value):
        if value is None:
            return '-'
        if isinstance(value, str):
            return value
        if isinstance(value, (list, tuple)):
            return ' '.join(f'{v:.6g}' for v in value)
        return f'{value:.6g}'

    return [(key, text(estimates.get(key))) for name in ESTIMATES
            for key in (name, f'{name}_bound', f'{name}_from')]


def robot_estimates(values):
    """A controller's report's values {key: text} -> {'command_latency' s,
    'motor_time_constant' s, 'wheel_gains': [left, right], 'dead_band': m/s, each with its
    '<name>_bound' (the same units) and '<name>_from' ('told', 'online', 'check'); None for
    '-'} (those it has).
    """
    out: dict[str, object] = {}
    for name in ESTIMATES:
        for key in (name, f'{name}_bound'):
            text = values.get(key)
            if text is not None:
                out[key] = (None if text == '-' else [float(v) for v in text.split()]
                            if name == 'wheel_gains' else float(text))
        source = values.get(f'{name}_from')
        if source is not None:
            out[f'{name}_from'] = None if source == '-' else source
    return out


def link_summary(reports):
    """One robot link from its robot_bridge's reports [(t s, level, message, {key: text})]
    (every report, or the newest and those that began a loss): the counts and latency
    percentiles (ms) of the last report, and the times (s) at which the link was lost or an
    error began (level 2 after a lower level).
    """
    last = reports[-1][3]
    summary: dict[str, object] = {key: int(last[key]) for key in LINK_COUNTS if key in last}
    for key in ('latency_ms_p50', 'latency_ms_p99'):
        if key in last:
            summary[key] = float(last[key])
    summary['last_error'] = last.get('last_error', '')
    levels = [0] + [level for _, level, _, _ in reports]
    summary['lost_at'] = [round(t, 3) for k, (t, level, _, _) in enumerate(reports)
                          if level >= 2 > levels[k]]
    return summary


def contacts_from_report(values):
    """The contact tally {'count', 'time', 'smallest_gap'} (and from MuJoCo 'walls',
    'largest_push') of a fake_arena diagnostic status given as {key: text} (None for a value
    it reports as None).
    """
    return {key: None if values[key] == 'None' else float(values[key])
            for key in CONTACT_KEYS if key in values}


# A world's contact tally: new robot-robot contacts, time with any (s), smallest gap between
# two bodies (m); from MuJoCo also new robot-wall contacts and the largest contact force (N).
CONTACT_KEYS = ('count', 'time', 'smallest_gap', 'walls', 'largest_push')
