"""Faults the tests inflict on a run's node processes: a node killed (a crash, a power cut)
and started again, as a lab's robot PC might do it.
"""

import signal

from curve_formation.run.runner import Run


def kill(run: Run, key: str, sig: int = signal.SIGKILL) -> int | None:
    """Kill one node process of the run; the graph forgets it (no death is reported for
    it) and counts the run as ended hard (it left shared memory). Returns its exit status.
    """
    graph = run.graph
    assert graph is not None, 'the run has not started'
    proc = graph.processes.pop(key)
    proc.send_signal(sig)
    proc.wait(10)
    graph.ended_hard = True
    return proc.returncode


def restart(run: Run, key: str) -> None:
    """Start a killed node of the run again; its log goes on after what it wrote before."""
    graph = run.graph
    assert graph is not None, 'the run has not started'
    graph.start(next(launch for launch in graph.launches if launch.key == key), mode='a')
