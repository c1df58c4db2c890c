"""Topic names. Per-robot topics are relative, so a robot is placed by its namespace."""

CURVE = '/formation/curve'
OBSERVED_CURVE = '/formation/observed_curve'
ESTOP = '/formation/estop'
# Curve subscribers that can receive from the curve server (readiness.py).
READY = '/formation/ready'
CURVE_PATH = '/formation/curve_path'
CURVE_MARKERS = '/formation/markers'
POSE = 'pose'
TRUE_POSE = 'true_pose'               # a fake robot's ground truth, when a camera tracks it
CAMERA_IMAGE = '/camera/image_raw'
CAMERA_POSES = '/camera/robot_poses'  # all robots, agent order (NaN = not seen)
CAMERA_DEBUG = '/camera/debug_image'
# Every robot's pose in one message, for the safety filter and re-assignment (messages.py).
ROBOT_POSES = '/formation/robot_poses'
CMD_VEL = 'cmd_vel'
STATE = 'formation_state'
ESTIMATE = 'disturbance_estimate'
TICK = 'control_tick'
DIAGNOSTICS = '/diagnostics'


def robot_namespace(index):
    """Namespace of robot `index` (1-based): /robot_<i>."""
    return f'/robot_{index}'


def robot_topic(index, name):
    """Absolute name of a per-robot topic, e.g. /robot_3/pose."""
    return f'{robot_namespace(index)}/{name}'
