"""A controller's command log (core.controller.command_log) as a class: the array and its
count, with Sent records in and out. What AgentController's predict_pose and its observer
read; the batch simulator's kernel keeps the same arrays per robot.

Times in s on the controller's clock; poses in the arena frame (m, rad); commands in m/s and
rad/s.
"""

from collections.abc import Iterator

import numpy as np

from curve_formation.core.base.shapes import FloatArray, Pose
from curve_formation.core.controller import command_log as log
from curve_formation.core.controller.inputs import Sent


def _sent(row: FloatArray) -> Sent:
    return Sent(float(row[log.AT]), float(row[log.V]), float(row[log.W]),
                (float(row[log.REF_V]), float(row[log.REF_W])),
                (float(row[log.SHIFT_V]), float(row[log.SHIFT_W])), bool(row[log.LIMITED]),
                bool(row[log.DRIVEN]), int(row[log.ESTIMATE]))


class CommandsSent:
    """The last `size` commands sent, oldest first: `rows` (size, command_log.FIELDS), of
    which the first `count` are in use.
    """

    def __init__(self, size: int) -> None:
        self.rows: FloatArray = np.zeros((size, log.FIELDS))
        self.count = 0

    def append(self, sent: Sent) -> None:
        self.count = log.log_append(self.rows, self.count, sent.at, sent.v, sent.w,
                                    *sent.reference, *sent.shift, sent.limited, sent.driven,
                                    sent.estimate)

    def __iter__(self) -> Iterator[Sent]:
        return (_sent(row) for row in self.rows[:self.count])

    def __len__(self) -> int:
        return self.count

    def acting(self, at: float, latency: float) -> Sent | None:
        """The command acting on the robot at `at` (command_log.log_acting); None if none."""
        k = log.log_acting(self.rows, self.count, at, latency)
        return None if k < 0 else _sent(self.rows[k])

    def realised(self, end: float, elapsed: float, latency: float, tau: float,
                 updates: int) -> Sent | None:
        """What the wheels did on average over the `elapsed` s up to `end`
        (command_log.log_realised) as a Sent at `end` with no (v, w); None if the commands
        sent do not reach back that far.
        """
        found, ref_v, ref_w, shift_v, shift_w, limited, driven, estimate = log.log_realised(
            self.rows, self.count, end, elapsed, latency, tau, updates)
        if not found:
            return None
        return Sent(end, 0.0, 0.0, (ref_v, ref_w), (shift_v, shift_w), limited, driven,
                    estimate)

    def predicted(self, pose: Pose, stamp: float, received: float, now: float,
                  latency: float, longest: float, drift: tuple[float, float]) -> Pose:
        """The pose taken at `stamp` (received at `received`) carried to `now` + `latency`
        (command_log.log_predicted).
        """
        return log.log_predicted(self.rows, self.count, *pose, stamp, received, now, latency,
                                 longest, *drift)
