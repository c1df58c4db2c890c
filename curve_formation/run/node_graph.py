"""Starts and stops an experiment's nodes: a process each, or all in the runner's executor."""

from dataclasses import dataclass
import os
from pathlib import Path
import signal
import subprocess
import sys
import time

import yaml

from curve_formation.nodes.runtime import PublicationCounter, PUBLICATIONS_ENV, shut_down
from curve_formation.run.launches import CONTROLLER_GROUP, node_class, NODE_GROUP


STOP_TIMEOUT = 10.0    # s for a group of nodes to exit after SIGINT before it is killed
PROCESS_CHECK_PERIOD = 0.2   # s between checks that every node process still runs


@dataclass(frozen=True)
class NodeDeath:
    """A node process that ended on its own: its key, when it was seen gone (s, time.time())
    and how ('killed by SIGKILL', 'exit status 1'), with the end of its log.
    """

    key: str
    when: float
    how: str
    log_tail: str


def how_it_ended(returncode):
    if returncode < 0:
        try:
            return f'killed by {signal.Signals(-returncode).name}'
        except ValueError:
            return f'killed by signal {-returncode}'
    return f'exit status {returncode}'


class NodeGraph:
    """The running nodes of a run. A context manager: stop() on exit.

    params_files: {launch key: parameters file} (launches.write_params_files); logs_dir gets
    each process's output; publications_dir (or None), each node's count of publications
    (runtime.PublicationCounter, for analysis.bag_accounting). host: the runner's
    observers.Observers, which spins while nodes stop and hosts them with single_process.
    """

    def __init__(self, launches, params_files, logs_dir, host, single_process=False,
                 publications_dir=None):
        self.launches = launches
        self.params_files = params_files
        self.logs_dir = logs_dir
        self.host = host
        self.single_process = single_process
        self.publications_dir = publications_dir
        self.processes = {}
        self.in_process = []    # (node, PublicationCounter or None)
        self.deaths = []        # NodeDeath of every process that ended on its own
        self.ended_hard = False  # a process died or was killed (it left shared memory)
        self.on_death = None    # called with each NodeDeath as it is found
        self._last_check = -float('inf')

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.stop()

    def start(self, launch, mode='w', overrides=None):
        """Start one node; its output goes to logs_dir/<key>.log (mode 'a': appended).
        overrides: {parameter: value} set over its parameters file for this start only.
        """
        overrides = overrides or {}
        if self.single_process:
            from rclpy.parameter import Parameter
            node = node_class(launch.program)(
                context=self.host.context, namespace=launch.namespace,
                parameter_overrides=[Parameter(k, value=v) for k, v
                                     in {**launch.parameters, **overrides}.items()])
            counter = PublicationCounter(node) if self.publications_dir is not None else None
            self.in_process.append((node, counter))
            self.host.add_node(node)
            return
        cmd = [sys.executable, '-m', launch.program, '--ros-args', '-r',
               f'__ns:={launch.namespace}', '--params-file', str(self.params_files[launch.key])]
        for key, value in overrides.items():
            cmd += ['-p', f'{key}:={yaml.safe_dump(value).splitlines()[0]}']
        self._popen(launch.key, cmd, mode)

    def _popen(self, key, cmd, mode='w'):
        """Start a node process `cmd` known as `key`, its output in logs_dir/<key>.log."""
        self.logs_dir.mkdir(parents=True, exist_ok=True)
        env = dict(os.environ, PYTHONUNBUFFERED='1')
        if self.publications_dir is not None:   # each node reports what it published
            env[PUBLICATIONS_ENV] = str(self.publications_dir)
        # A session of its own: a Ctrl-C at the terminal reaches the runner alone, which stops
        # the nodes in order; and where the kernel shares the cores between sessions
        # (autogroups), a busy program in another session cannot take the run's share. The
        # runner's session (a process group each) was measured: better beside a nice-19 job
        # started from the same terminal, a hundred robots at 4.6 Hz beside one in another
        # (docs/performance.md, "A session per node process").
        with open(self.logs_dir / f'{key}.log', mode) as log_file:
            self.processes[key] = subprocess.Popen(
                cmd, env=env, stdout=log_file, stderr=subprocess.STDOUT,
                start_new_session=True, preexec_fn=_stop_with_parent)

    def start_group(self, group):
        """Start a GroupLaunch's nodes in one process (nodes.node_group, from its group file
        beside their parameters files), its output in logs_dir/<key>.log.
        """
        folder = Path(self.params_files[group.launches[0].key]).parent
        self._popen(group.key, [sys.executable, '-m', NODE_GROUP,
                                str(folder / group.file_name)])

    def check_processes(self):
        """Note every node process that ended on its own (deaths, on_death) and forget it;
        returns False (a predicate for Run.spin_until that never ends a wait).

        Looks at most every PROCESS_CHECK_PERIOD s (it is called between callbacks).
        """
        now = time.monotonic()
        if now - self._last_check < PROCESS_CHECK_PERIOD:
            return False
        self._last_check = now
        for key, proc in list(self.processes.items()):
            if proc.poll() is not None:
                del self.processes[key]
                try:
                    tail = (self.logs_dir / f'{key}.log').read_text(errors='replace')[-2000:]
                except OSError:
                    tail = ''
                death = NodeDeath(key, time.time(), how_it_ended(proc.returncode), tail)
                self.deaths.append(death)
                self.ended_hard = True
                if self.on_death is not None:
                    self.on_death(death)
        return False

    def stop(self):
        """SIGINT every node process (they send a last zero command), then kill what lingers;
        in-process nodes run their shutdown hooks (the host destroys them once it stops).

        Controllers first, so that their last ticks and zero commands are acknowledged by
        the fake robots and the recorder, which are all still there; the host spins
        meanwhile, so the recorder keeps draining its queue.
        """
        first = {k: p for k, p in self.processes.items()
                 if k.endswith('formation_controller') or k.startswith(CONTROLLER_GROUP)}
        for group in (first, {k: p for k, p in self.processes.items() if k not in first}):
            deadline = time.monotonic() + STOP_TIMEOUT   # for the whole group together
            for proc in group.values():
                if proc.poll() is None:
                    proc.send_signal(signal.SIGINT)
            while time.monotonic() < deadline and any(p.poll() is None for p in group.values()):
                self.host.spin_once()
            for proc in group.values():
                if proc.poll() is None:
                    proc.kill()
                    proc.wait(5)
        self.processes = {}
        if not self.in_process:
            return
        self.host.drain()
        shut_down([node for node, _ in self.in_process])
        for node, counter in self.in_process:
            if counter is not None:
                counter.save(self.publications_dir, node.get_fully_qualified_name())
        self.in_process = []


def _stop_with_parent():
    """In a node process: receive SIGINT when the runner dies, even if it is killed hard."""
    try:
        import ctypes
        ctypes.CDLL('libc.so.6', use_errno=True).prctl(1, signal.SIGINT)  # PR_SET_PDEATHSIG
    except OSError:
        pass
