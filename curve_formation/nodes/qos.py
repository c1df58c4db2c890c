"""QoS profiles, chosen for the data they carry."""

from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.qos import (
                       DurabilityPolicy,
                       HistoryPolicy,
                       qos_profile_sensor_data,
                       QoSProfile,
                       ReliabilityPolicy,
)


# Poses and images: latest wins, drops are fine.
SENSOR = qos_profile_sensor_data
# Velocity commands: reliable, only the newest matters.
COMMAND = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                     reliability=ReliabilityPolicy.RELIABLE)
# A neighbour's state: reliable and shallow; stale values are rejected by stamp anyway.
STATE = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=2,
                   reliability=ReliabilityPolicy.RELIABLE)
# The curve and its visualisation: latched, so a late joiner gets the current one.
LATCHED = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                     reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
# The start-up handshake (readiness.py): one message from each of many writers, all kept (a
# reader's KEEP_LAST history is shared by every writer of a topic, so a shallow one would
# drop some), and latched for a curve server that starts late.
ROLL_CALL = QoSProfile(history=HistoryPolicy.KEEP_ALL,
                       reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL)
# Diagnostics and the e-stop: reliable, a few deep.
EVENTS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5,
                    reliability=ReliabilityPolicy.RELIABLE)
# E-stop commands as read: best effort and volatile, which every writer matches (volatile or
# transient-local, reliable or best-effort: `ros2 topic pub`, an RViz or Foxglove button, a
# foot-pedal script). Nodes that act on the e-stop also read them with ESTOP_RELIABLE, so a
# reliable sender's retransmissions reach them (nodes/estop.py).
ANY_PUBLISHER = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                           reliability=ReliabilityPolicy.BEST_EFFORT,
                           durability=DurabilityPolicy.VOLATILE)
ESTOP_RELIABLE = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                            reliability=ReliabilityPolicy.RELIABLE,
                            durability=DurabilityPolicy.VOLATILE)
# Camera frames: only the newest is worth processing; an older one would only add latency.
IMAGE = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                   reliability=ReliabilityPolicy.BEST_EFFORT)


def observer_events():
    """Event callbacks for the runner's own observers (monitor, recorder): none.

    rclpy gives every subscription two QoS event handlers by default (incompatible QoS and
    type warnings), and its executor walks every handler on every wait: for a monitor of nine
    robots that is 76 extra entities per wait. The observers use this module's profiles, so
    the warnings could not fire.
    """
    return SubscriptionEventCallbacks(use_default_callbacks=False)
