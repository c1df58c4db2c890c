"""A formation_controller whose formation_state messages are lost before they are published,
each with probability STATE_DROP_ENV (a lossy link between controllers, for the tests; run in
the package's place through RunOptions.node_variants).
"""

import os
from typing import Any

import numpy as np

from curve_formation.core.controller.inputs import State
from curve_formation.nodes.formation_controller import FormationController
from curve_formation.nodes.runtime import run_node


STATE_DROP_ENV = 'CURVE_FORMATION_TEST_STATE_DROP'
MODULE = 'lossy_controller'


class LossyController(FormationController):
    """FormationController that drops a share of its states."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.drop = float(os.environ.get(STATE_DROP_ENV, '0'))
        self.rng = np.random.default_rng()

    def publish_state(self, state: State) -> None:
        if self.rng.random() >= self.drop:
            super().publish_state(state)


NODE_CLASS = LossyController


def main() -> int:
    return run_node(LossyController)


if __name__ == '__main__':
    raise SystemExit(main())
