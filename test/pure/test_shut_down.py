"""How a process's nodes end (nodes/runtime.py shut_down): every node's last messages go out
before any wait for their acknowledgement, and the waits share one start.
"""

import time

from curve_formation.nodes.runtime import shut_down


class Unacknowledged:
    """A publisher whose readers never acknowledge: each wait lasts its whole timeout."""

    def __init__(self, events):
        self.events = events

    def wait_for_all_acked(self, timeout):
        seconds = timeout.nanoseconds * 1e-9
        self.events.append(('wait', round(seconds, 2)))
        time.sleep(seconds)
        return False


class Ending:
    def __init__(self, name, events, waits):
        self.name, self.events, self.waits = name, events, waits

    def on_shutdown(self):
        self.events.append(('sent', self.name))
        return [(Unacknowledged(self.events), s) for s in self.waits]


def test_nodes_send_their_last_messages_before_any_wait_and_wait_together():
    """Three nodes, waits of 0.3 s and three of 0.1 s for readers that never acknowledge:
    all sent first, then the first wait takes its 0.3 s and the others nothing left (one
    after the other, 0.6 s); a node without a hook, or whose hook returns None, is passed.
    """
    events = []

    class Quiet:
        def on_shutdown(self):
            events.append(('sent', 'quiet'))

    shut_down([Ending('a', events, [0.3, 0.1]), object(), Quiet(), Ending('b', events, [0.1]),
               Ending('c', events, [0.1])])
    assert events[:4] == [('sent', 'a'), ('sent', 'quiet'), ('sent', 'b'), ('sent', 'c')]
    waits = [seconds for kind, seconds in events[4:]]
    assert len(waits) == 4 and waits[0] == 0.3 and all(w < 0.05 for w in waits[1:]), waits
