"""A process that builds several nodes before it spins (nodes/runtime.py run_nodes): their
ticks start evenly as the executor starts, not in a burst of the periods missed meanwhile.
"""

import time

import numpy as np
from rclpy.node import Node

from curve_formation.nodes.runtime import restart_timers


def test_timers_of_nodes_built_before_the_spin_start_their_periods_with_it(ros):
    """Three nodes built 0.2 s apart (a group of controllers takes about that each on a
    loaded machine): restarted, every 10 Hz timer first fires within a period of the restart,
    the three a third of a period apart, and keeps its period (unrestarted, the first node's
    fired its missed ticks at once); a cancelled timer stays cancelled.
    """
    context, add, spin_until = ros
    ticks = {k: [] for k in range(3)}
    cancelled = []
    nodes = []
    for k in range(3):
        node = add(Node(f'built_{k}', context=context))
        node.create_timer(0.1, lambda k=k: ticks[k].append(time.monotonic()))
        node.create_timer(0.1, lambda: cancelled.append(time.monotonic())).cancel()
        nodes.append(node)
        time.sleep(0.2)
    restarted = time.monotonic()
    restart_timers(nodes)
    spin_until(lambda: min(len(times) for times in ticks.values()) >= 6)
    firsts = np.array([times[0] for times in ticks.values()]) - restarted
    assert np.all((firsts > 0.07) & (firsts < 0.2)), np.round(firsts, 3)
    assert np.all(np.abs(np.diff(firsts) - 0.1 / 3) < 0.02), np.round(firsts, 3)
    for k, times in ticks.items():
        intervals = np.diff(times)
        assert np.all(np.abs(intervals - 0.1) < 0.03), (k, np.round(intervals, 3))
    assert not cancelled
