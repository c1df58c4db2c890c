"""Shared fixtures: experiment dictionaries to break on purpose, a private ROS context."""

import os
from pathlib import Path
import random
import sys

import pytest
import yaml


sys.path.insert(0, str(Path(__file__).parent))
# test support: code the tests run in the package's place (e.g. a lossy controller)
SUPPORT = Path(__file__).resolve().parent / 'support'
sys.path.insert(0, str(SUPPORT))

from curve_formation.paths import use_dds_profile  # noqa: E402


use_dds_profile()   # as the CLI and every node do, before any ROS context in this process
# Nothing a test starts leaves this machine, nor meets another test run's nodes, even where it
# uses no ros_domain fixture: `run` takes the caller's domain and discovery range.
os.environ['ROS_DOMAIN_ID'] = str(random.SystemRandom().randint(102, 200))
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'

CONFIG_DIR = Path(__file__).resolve().parent.parent / 'config'


def pytest_collection_modifyitems(items):
    """A test on a ROS context or domain of its own is a `ros` test, whether or not its module
    says so: the default run (scripts/test) spreads the tests marked `not ros` over the cores
    and runs the `ros` ones one at a time, their nodes having the machine to themselves.
    Within them, the tiers: `in_process` (rclpy nodes on a context of the test's own, the
    `ros` fixture) and `processes` (the others: node processes on a private domain).
    """
    for item in items:
        fixtures = set(getattr(item, 'fixturenames', ()))
        if {'ros', 'ros_domain'} & fixtures:
            item.add_marker(pytest.mark.ros)
        if item.get_closest_marker('ros') is not None:
            item.add_marker(pytest.mark.in_process if 'ros' in fixtures
                            else pytest.mark.processes)


@pytest.fixture
def closed_curve_dict():
    """The shipped closed-curve experiment as a plain dict (a fresh copy per test)."""
    return yaml.safe_load((CONFIG_DIR / 'closed_curve.yaml').read_text())


@pytest.fixture
def arena_dict():
    return yaml.safe_load((CONFIG_DIR / 'mona_arena.yaml').read_text())


def paper_arena():
    """The shipped Mona arena case with the paper's agents, graph and law
    (core.config.experiment.as_in_the_paper).
    """
    from curve_formation.core.config.loading import as_in_the_paper, build_experiment
    data = yaml.safe_load((CONFIG_DIR / 'mona_arena.yaml').read_text())
    return build_experiment(as_in_the_paper(data), 'mona_arena (paper agents and graph)')

DATA_DIR = Path(__file__).resolve().parent / 'data'


def no_history_qos():
    """Reliable, volatile: a reader given none of a latched writer's history, as a late
    joiner is when Fast DDS fails to deliver it.
    """
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    return QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


def private_domain():
    """A random ROS_DOMAIN_ID for one test's nodes, from TEST_DOMAINS ('LOW-HIGH', default
    1-101): scripts/test gives each of the streams of `ros` tests it runs at once a range of
    its own, so that two tests running at the same time never share a domain.
    """
    low, high = map(int, os.environ.get('TEST_DOMAINS', '1-101').split('-'))
    return random.SystemRandom().randint(low, high)


@pytest.fixture
def ros_domain(monkeypatch):
    """A private ROS_DOMAIN_ID for this test, DDS discovery on this machine only."""
    domain = private_domain()
    monkeypatch.setenv('ROS_DOMAIN_ID', str(domain))
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    return domain


@pytest.fixture
def ros(ros_domain):
    """(context, add, spin_until) on a private context; everything torn down after."""
    import time

    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor

    context = Context()
    rclpy.init(context=context)
    executor = SingleThreadedExecutor(context=context)
    nodes = []

    def add(node):
        nodes.append(node)
        executor.add_node(node)
        return node

    def spin_until(predicate, timeout=10.0):
        deadline = time.monotonic() + timeout
        while not predicate():
            assert time.monotonic() < deadline, 'timed out'
            executor.spin_once(timeout_sec=0.02)

    yield context, add, spin_until
    executor.shutdown()
    for node in nodes:
        node.destroy_node()
    rclpy.try_shutdown(context=context)


def pytest_sessionfinish(session, exitstatus):
    """Remove the Fast DDS shared-memory files that the runs' hard kills left in /dev/shm
    (what `curve-formation clean-shm` does), so that test runs do not fill it.
    """
    import contextlib
    import subprocess

    from curve_formation.dds_shm import clean
    with contextlib.suppress(OSError, subprocess.SubprocessError):
        clean(quiet=True)
