"""Topic names. Per-robot topics are relative, so a robot is placed by its namespace."""

CURVE = '/formation/curve'
OBSERVED_CURVE = '/formation/observed_curve'
ESTOP = '/formation/estop'
CURVE_PATH = '/formation/curve_path'
CURVE_MARKERS = '/formation/markers'
POSE = 'pose'
CMD_VEL = 'cmd_vel'
STATE = 'formation_state'
ESTIMATE = 'disturbance_estimate'
DIAGNOSTICS = '/diagnostics'


def robot_namespace(index):
    """Namespace of robot `index` (1-based): /robot_<i>."""
    return f'/robot_{index}'


def robot_topic(index, name):
    """Absolute name of a per-robot topic, e.g. /robot_3/pose."""
    return f'{robot_namespace(index)}/{name}'
