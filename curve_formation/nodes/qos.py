"""The QoS profiles of interface.QOS as rclpy QoSProfiles."""

from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from curve_formation.interface import QOS, QosSpec


def profile(spec: QosSpec) -> QoSProfile:
    """The rclpy QoSProfile of a profile given as data (interface.QOS)."""
    reliability = (ReliabilityPolicy.RELIABLE if spec.reliable
                   else ReliabilityPolicy.BEST_EFFORT)
    durability = (DurabilityPolicy.TRANSIENT_LOCAL if spec.transient_local
                  else DurabilityPolicy.VOLATILE)
    if spec.depth is None:
        return QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=reliability,
                          durability=durability)
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=spec.depth,
                      reliability=reliability, durability=durability)


# The profiles by name, each chosen for the data it carries (interface.QOS says why).
SENSOR = profile(QOS['SENSOR'])
COMMAND = profile(QOS['COMMAND'])
STATE = profile(QOS['STATE'])
LATCHED = profile(QOS['LATCHED'])
ROLL_CALL = profile(QOS['ROLL_CALL'])
EVENTS = profile(QOS['EVENTS'])
ANY_PUBLISHER = profile(QOS['ANY_PUBLISHER'])
ESTOP_RELIABLE = profile(QOS['ESTOP_RELIABLE'])
IMAGE = profile(QOS['IMAGE'])


def observer_events() -> SubscriptionEventCallbacks:
    """Event callbacks for the runner's own observers (monitor, recorder): none.

    rclpy gives every subscription two QoS event handlers by default (incompatible QoS and
    type warnings), and its executor walks every handler on every wait: for a monitor of nine
    robots that is 76 extra entities per wait. The observers use this module's profiles, so
    the warnings could not fire.
    """
    return SubscriptionEventCallbacks(use_default_callbacks=False)
