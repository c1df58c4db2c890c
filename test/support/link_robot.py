"""The robot's end of an emulated link (links.UdpEndpoint or PtyEndpoint), read as the Mona
firmware would: for the robot bridge's tests.
"""

import time

from curve_formation import wire


MONA = wire.PRESETS['mona-serial']
RADIUS, BASE = 0.015, 0.08   # the wheel radius and base the tests' bridges are given (m)


class Robot:
    """The robot's end of a link: every line with its arrival time; answers 'ok' if told to."""

    def __init__(self, endpoint, answer=True):
        self.endpoint, self.answer = endpoint, answer
        self.lines = []

    def poll(self):
        for line in self.endpoint.lines():
            self.lines.append((time.monotonic(), wire.decode(MONA, line, RADIUS)))
            if self.answer:
                self.endpoint.send(b'ok\n')

    def said(self, since=0.0):
        return [said for t, said in self.lines if t >= since]
