"""A test "host" whose clock disagrees with the others': a Python process started with this
folder on PYTHONPATH and HOST_CLOCK_OFFSET_ENV set (seconds) reads its nodes' clock
(curve_formation.nodes.runtime.now_seconds) that far ahead. now_seconds is replaced as its
module loads, before any node imports it, so every node of the process reads the same clock.
"""

import importlib.abc
import importlib.util
import os
import sys


HOST_CLOCK_OFFSET_ENV = 'CURVE_FORMATION_TEST_CLOCK_OFFSET'
RUNTIME = 'curve_formation.nodes.runtime'


class _ShiftedClock(importlib.abc.MetaPathFinder):
    """Finds the runtime module as usual, and shifts its now_seconds once it has run."""

    def __init__(self, offset):
        self.offset = offset

    def find_spec(self, name, path, target=None):
        if name != RUNTIME:
            return None
        sys.meta_path.remove(self)   # the module is found once; let the others find it
        spec = importlib.util.find_spec(name)
        loader, offset = spec.loader, self.offset
        run_module = loader.exec_module

        def exec_module(module):
            run_module(module)
            unshifted = module.now_seconds
            module.now_seconds = lambda node: unshifted(node) + offset

        loader.exec_module = exec_module
        return spec


if os.environ.get(HOST_CLOCK_OFFSET_ENV):
    sys.meta_path.insert(0, _ShiftedClock(float(os.environ[HOST_CLOCK_OFFSET_ENV])))
