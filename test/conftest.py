"""Shared fixtures: experiment dictionaries to break on purpose, a private ROS context."""

import os
from pathlib import Path
import random
import sys

import pytest
import yaml


TESTS = Path(__file__).resolve().parent
ROOT = TESTS.parent   # the project
sys.path.insert(0, str(TESTS))
# test support: what tests of several tiers share, and code the tests run in the package's
# place (e.g. a lossy controller)
SUPPORT = TESTS / 'support'
sys.path.insert(0, str(SUPPORT))

from curve_formation.paths import use_dds_profile  # noqa: E402


use_dds_profile()   # as the CLI and every node do, before any ROS context in this process
# Nothing a test starts leaves this machine, nor meets another test run's nodes, even where it
# uses no ros_domain fixture: `run` takes the caller's domain and discovery range.
os.environ['ROS_DOMAIN_ID'] = str(random.SystemRandom().randint(102, 200))
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'

CONFIG_DIR = ROOT / 'config'


TIERS = ('pure', 'in_process', 'processes')
RUNS_NODE_PROCESSES = frozenset({'recorded'})   # session fixtures that run node processes


def pytest_collection_modifyitems(items):
    """A test's folder is its tier, and its markers: pure/ (no DDS; the default run,
    scripts/test, spreads them over the cores), in_process/ (rclpy nodes on a context of the
    test's own, the `ros` fixture) and processes/ (node processes on a private domain); the
    last two are also `ros`, run one at a time, their nodes having the machine to themselves;
    a test on a recorded run (RUNS_NODE_PROCESSES) is in processes/, whose session records it
    once for all. A test whose fixtures say another tier than its folder is refused at
    collection.
    """
    misplaced = []
    for item in items:
        tier = item.path.parent.name
        fixtures = set(getattr(item, 'fixturenames', ()))
        says = ('processes' if fixtures & RUNS_NODE_PROCESSES
                else 'in_process' if 'ros' in fixtures
                else 'processes' if 'ros_domain' in fixtures else None)
        if tier not in TIERS or (says is not None and says != tier) or (
                tier == 'in_process' and says is None):
            misplaced.append(f'{item.nodeid}: in {tier}/, its fixtures say '
                             f'{says or "no ros context"}')
        item.add_marker(tier)
        if tier != 'pure':
            item.add_marker(pytest.mark.ros)
    if misplaced:
        raise pytest.UsageError('tests in the wrong tier folder (test/pure, test/in_process, '
                                'test/processes):\n  ' + '\n  '.join(misplaced))


def quiet(*_):
    """A log (a run's, a pre-flight's) that says nothing."""


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

DATA_DIR = TESTS / 'data'


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
    its own, so that two tests running at the same time never share a domain; within a
    stream spread over pytest-xdist workers, each worker takes its share of the range.
    """
    low, high = map(int, os.environ.get('TEST_DOMAINS', '1-101').split('-'))
    workers = int(os.environ.get('PYTEST_XDIST_WORKER_COUNT', '1'))
    if workers > 1:
        share = (high - low + 1) // workers
        low += share * int(os.environ['PYTEST_XDIST_WORKER'].removeprefix('gw'))
        high = low + share - 1
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


@pytest.fixture
def ros_env(ros_domain):
    """The environment for a process of this test's, on its private domain."""
    return dict(os.environ)


@pytest.fixture(scope='session')
def colcon_install(tmp_path_factory):
    """colcon build of a copy of the tracked sources; returns the install prefix."""
    import shutil
    import subprocess

    if shutil.which('colcon') is None:
        pytest.fail('colcon is not installed: run the tests through scripts/test')
    ws = tmp_path_factory.mktemp('ws')
    files = subprocess.run(['git', 'ls-files', '--cached', '--others', '--exclude-standard'],
                           cwd=ROOT, capture_output=True, text=True, check=True).stdout.split()
    for name in files:
        if (ROOT / name).is_file():
            (ws / 'src' / 'curve_formation' / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / name, ws / 'src' / 'curve_formation' / name)
    proc = subprocess.run(['colcon', 'build', '--base-paths', 'src'], cwd=ws,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return ws / 'install' / 'curve_formation'


@pytest.fixture(scope='session')
def params_dir(tmp_path_factory):
    """What `curve-formation params arena_demo --out DIR --controllers-per-process 1` writes
    (a parameters file and a start line per node, on any PC): DIR.
    """
    import subprocess

    out = tmp_path_factory.mktemp('params')
    proc = subprocess.run([sys.executable, '-m', 'curve_formation.cli', 'params', 'arena_demo',
                           '--out', str(out), '--controllers-per-process', '1'],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    return out


@pytest.fixture(scope='session')
def recorded(tmp_path_factory):
    """A 6 s run of the fast closed-curve experiment, recorded to a sqlite3 bag (the MCAP
    default is recorded by test_analysis): (its folder, its results as the run wrote them).
    """
    from curve_formation.run.run_options import RunOptions
    from curve_formation.run.runner import Run

    folder = tmp_path_factory.mktemp('recorded')
    saved = os.environ['ROS_DOMAIN_ID']   # conftest's, for this test session
    os.environ['ROS_DOMAIN_ID'] = str(private_domain())
    options = RunOptions(bag_path=folder / 'bag', bag_storage='sqlite3')
    with Run(DATA_DIR / 'fast_closed.yaml', folder / 'run', options, log=lambda *_: None) as run:
        run.spin_for(6.0)
        live = run.write_results()
    os.environ['ROS_DOMAIN_ID'] = saved
    return folder, live


def pytest_sessionfinish(session, exitstatus):
    """Remove the Fast DDS shared-memory files that the runs' hard kills left in /dev/shm
    (what `curve-formation clean-shm` does), so that test runs do not fill it.
    """
    from curve_formation.dds_shm import remove_dead_shared_memory
    remove_dead_shared_memory()
