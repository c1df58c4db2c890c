"""What one controller hears from the robots it receives from: each in-neighbour's last
state, and the newest news of the leader relayed through them (the heartbeat that stops a
follower whose leader is gone).

Leader heartbeat: every state carries the age of the newest news of the leader its sender
has when its pose was taken (the leader: its pose is the news); a receiver dates that news on
its own clock (when that pose was taken, by the sender's stamps: StampClock, minus the age)
and keeps the newest. Times in s: stamps on their source's clock, receipts on this
controller's.
"""

import numpy as np

from curve_formation.core.base.shapes import FloatArray, IntArray, Point
from curve_formation.core.controller.agent_config import AgentConfig
from curve_formation.core.controller.inputs import (
    is_stale,
    MAX_PREDICTION,
    Neighbour,
    StampClock,
)


NO_ERRORS = np.zeros((0, 2))


class Neighbourhood:
    """The in-neighbours of agent config.index and the news of the leader they relay."""

    def __init__(self, config: AgentConfig) -> None:
        self.config = config
        self.neighbours = {j: Neighbour() for j, _ in config.neighbours}
        # the in-neighbours as consensus_feedback takes them: rows of their errors, weights,
        # and this agent's own weight (1 for the leader, the pinning for a follower)
        self.sources: IntArray = np.arange(len(config.neighbours))
        self.weights: FloatArray = np.array([w for _, w in config.neighbours], dtype=float)
        self.pin = 1.0 if config.is_leader else config.pinning
        # when the newest news of the leader was made (this controller's clock); the clocks of
        # the stamps it is dated by (own poses, each in-neighbour's states)
        self.leader_heard: float | None = None
        self.stamp_clocks = {j: StampClock(config.shared_clock)
                             for j in (config.index, *self.neighbours)}

    def own_pose(self, stamp: float, received: float) -> float:
        """The own pose stamped `stamp` came at `received`: when it was taken, by the own
        pose source's StampClock (the leader's pose is its news).
        """
        if self.config.is_leader:
            self.leader_heard = received
        return self.stamp_clocks[self.config.index].date(stamp, received)

    def heard(self, j: int, error: Point, curve_id: int, stamp: float, received: float,
              leader_age: float | None) -> None:
        """In-neighbour j's state (checked by the caller), with its news of the leader."""
        self.neighbours[j] = Neighbour(error, int(curve_id), stamp, received)
        if leader_age is not None:
            news = min(received, self.stamp_clocks[j].date(stamp, received) - leader_age)
            if self.leader_heard is None or news > self.leader_heard:   # not ahead of us
                self.leader_heard = news

    def leader_age(self, pose_dated: float) -> float | None:
        """The age of the newest news of the leader when the own pose was taken (negative,
        down to -MAX_PREDICTION, for news that came after; None before any).
        """
        if self.leader_heard is None:
            return None
        return max(-MAX_PREDICTION, pose_dated - self.leader_heard)

    def leader_silent(self, now: float) -> str | None:
        """Why a follower must stop at `now` for want of news of the leader (none within
        leader_timeout plus the time its relay may take, leader_relay); None if it may go on
        (and always for the leader).
        """
        timeout = self.config.leader_timeout + self.config.leader_relay
        if self.config.is_leader or not is_stale(self.leader_heard, now, timeout):
            return None
        return ('no news from the leader yet' if self.leader_heard is None
                else f'no news from the leader ({now - self.leader_heard:.2f} s old)')

    def silent(self, j: int, now: float) -> str | None:
        """Why in-neighbour j's state cannot be used at `now` (never heard, or stale); None
        if it can.
        """
        nb = self.neighbours[j]
        if nb.received is None:
            return f'no state from neighbour {j} yet'
        if is_stale(nb.received, now, self.config.neighbour_timeout):
            return f'neighbour {j} stale ({now - nb.received:.2f} s old)'
        return None

    def stamps(self) -> tuple[tuple[int, float | None], ...]:
        """((j, stamp), ...) of the in-neighbour states held."""
        return tuple((j, nb.stamp) for j, nb in self.neighbours.items())
