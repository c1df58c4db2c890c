"""Replay loops until stopped (the recorded bag's types and hashes: test/processes/
test_bag_type_hashes.py, beside the run that records it).
"""

import threading

import rclpy

from cases import tiny_bag


def test_replay_loops_until_stopped(tmp_path, ros):
    from std_msgs.msg import Bool

    from curve_formation.bags.replay import replay
    context, add, spin_until = ros
    bag = tiny_bag(tmp_path / 'bag')
    node = add(rclpy.create_node('player', context=context))
    received = []
    node.create_subscription(Bool, '/replay_test', lambda m: received.append(m.data), 10)
    stop = threading.Event()

    def joins():
        # The bag is F T F T F; passes join as ... F F T ...: two joins = 3 passes played.
        return sum(a is False and b is False
                   for a, b in zip(received, received[1:], strict=False))

    player = threading.Thread(target=replay, args=(node, bag), kwargs=dict(
        loop=True, clock=False, wait_for_subscribers=5.0, stop=stop, log=lambda *_: None))
    player.start()
    try:
        spin_until(lambda: joins() >= 2, timeout=10.0)
    finally:
        stop.set()
        player.join(5.0)
    assert not player.is_alive()   # and the stop event ended the loop
