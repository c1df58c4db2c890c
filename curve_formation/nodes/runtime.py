"""Running a node as a console script: init, spin, clean shutdown, clear start-up errors."""

from collections.abc import Callable, Iterable, Iterator, Sequence
import contextlib
import faulthandler
import inspect
import json
import os
from pathlib import Path
import signal
import sys
import threading
import time
from typing import Any, Optional

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import rclpy
from rclpy.context import Context
from rclpy.duration import Duration
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.signals import SignalHandlerOptions

from curve_formation.bags.streams import stream_key
from curve_formation.nodes.command_line import (
    check_params_files,
    help_text,
    parameter_value,
    parse,
)
from curve_formation.nodes.params import ParameterError
from curve_formation.paths import use_dds_profile
from curve_formation.scheduling import NORMAL, priority_problem, realtime_process


SIGNAL_CHECK_PERIOD = 0.2   # s, longest wait before a signal is acted on
EXIT_DEADLINE = 15.0        # s from a stop signal to a forced exit (_exit_hard_after)
# Which rclpy executor spins a node process: 'events' (rclpy's EventsExecutor, callbacks
# dispatched from C++) or 'single' (SingleThreadedExecutor, which rebuilds its wait set in
# Python on every wake-up).
EXECUTOR_ENV = 'CURVE_FORMATION_EXECUTOR'
# Fault injection: seconds added to every stamp and time this process's nodes take from their
# clock, as on a host whose clock is that far ahead (namespaces share the kernel's clock).
EXECUTORS = ('events', 'single')
# Set by the runner: a folder where each node process writes, when it ends, how many messages
# it published per writer stream (to check that a bag lost nothing).
PUBLICATIONS_ENV = 'CURVE_FORMATION_PUBLICATIONS'
RECORDER_NODE = 'formation_recorder'
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


def writer_key(topic: str, msg: Any) -> str:
    """Names one writer's stream within a topic, the same way for publisher and recorder.

    A formation topic has one writer, so its name suffices; /diagnostics and
    /formation/estop_state have many: each of our nodes puts its own name first in its
    DiagnosticArray, or as its DiagnosticStatus's name, so that name is added.
    """
    if isinstance(msg, DiagnosticArray) and msg.status:
        return stream_key(topic, msg.status[0].name)
    if isinstance(msg, DiagnosticStatus):
        return stream_key(topic, msg.name)
    return stream_key(topic)


class PublicationCounter:
    """Counts a node's publications per writer stream (see writer_key), from its first one.

    A DDS writer numbers its samples 1, 2, ... in publish order, and the recorder notes the
    first number it received of each stream; so what it should hold is every publication from
    that one on, however late it was matched (see analysis.bag_accounting).
    """

    def __init__(self, node: Node) -> None:
        self.counts: dict[str, int] = {}
        for publisher in node.publishers:
            self._wrap(publisher)

    def _wrap(self, publisher: Publisher) -> None:
        topic = publisher.topic_name
        publish = publisher.publish

        def counted(msg: Any) -> None:
            key = writer_key(topic, msg)
            self.counts[key] = self.counts.get(key, 0) + 1
            publish(msg)
        publisher.publish = counted  # type: ignore[method-assign]

    def save(self, folder: str | Path, name: str) -> None:
        path = Path(folder) / f'{name.strip("/").replace("/", ".")}.json'
        path.write_text(json.dumps(self.counts))


def now_seconds(node: Node) -> float:
    """The node's clock (sim time when use_sim_time is set) in seconds."""
    return node.get_clock().now().nanoseconds * 1e-9


def run_node(node_factory: Callable[..., Node], args: list[str] | None = None,
             large_data: bool = False, priority_parameter: str | None = None) -> int:
    """Create the node, spin it until Ctrl-C, SIGTERM or shutdown, then shut it down cleanly.

    `--help` prints the node's parameters (nodes.command_line) and returns 0. A parameters
    file that is not one, or sets nothing for this node, and a ParameterError at start end the
    process with one line on stderr and exit status 2.
    A node may define on_shutdown() (e.g. to send a last zero command; see shut_down); it
    runs before the node is destroyed, which is why rclpy's own SIGINT handler (it would shut
    the context down first) is replaced. Once the node runs, SIGINT and SIGTERM only set a
    flag that ends the spin loop: an exception raised inside an rclpy call (e.g. while a
    message is being converted) would come out as a RuntimeError, not as an interrupt.
    priority_parameter: the node's parameter (in its module's PARAMETERS) that gives its
    process's SCHED_FIFO priority, read from the command line before ROS starts (run_nodes).
    """
    module = inspect.getmodule(node_factory)
    priority = NORMAL
    name = getattr(module, 'NODE_NAME', None)   # a node module's (its console script's)
    if name is not None:
        command_line = parse(sys.argv if args is None else args, name)
        if command_line.help:
            print(help_text(name, module))
            return 0
        try:
            check_params_files(command_line)
            if priority_parameter is not None:
                (declared,) = [p for p in getattr(module, 'PARAMETERS', ())
                               if p.name == priority_parameter]
                priority = checked_priority(priority_parameter, parameter_value(
                    command_line, priority_parameter, declared.default))
        except ParameterError as exc:
            print(f'error: {exc}', file=sys.stderr)
            return 2
    return run_nodes([node_factory], args, large_data, priority)


def run_nodes(node_factories: Sequence[Callable[..., Node]], args: list[str] | None = None,
              large_data: bool = False, priority: int = 0) -> int:
    """run_node's life (signals, shutdown hooks, a bounded exit) for several nodes in one
    process: one context and one executor, as a ROS component container holds them.

    priority: SCHED_FIFO priority (1-99) the process takes before ROS starts, so that every
    thread it starts (DDS, the executor's timers) has it too; 0 = normal scheduling. Refused
    (no permission): a note on stderr, and the process runs at normal priority.
    """
    use_dds_profile(large_data=large_data)   # before the first ROS context; see paths
    why_not = realtime_process(priority)
    if why_not:
        print(f'note: realtime priority {priority} not taken ({why_not}; it needs root, '
              'CAP_SYS_NICE or an rtprio limit): running at normal priority, where a busy '
              'PC delays the ticks (docs/performance.md)', file=sys.stderr)
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    stop = threading.Event()
    # Installed explicitly: a process started from a background job inherits SIGINT ignored.
    # A signal while the node is built only asks it to stop once built, so that it still ends
    # through its shutdown (e.g. the recorder writes what it already received); a second one
    # interrupts the building (it may block, e.g. opening a camera).
    def while_building(signum: int, frame: Any) -> None:
        if stop.is_set():
            raise KeyboardInterrupt(f'signal {signum}')
        request_stop()

    def request_stop(*_: Any) -> None:
        if not stop.is_set():
            _exit_hard_after(EXIT_DEADLINE)
        stop.set()
    _on_stop_signals(while_building)
    nodes: list[tuple[Node, PublicationCounter | None]] = []
    status = 0
    try:
        executor = make_executor()
        for factory in node_factories:
            node = factory()
            counter = PublicationCounter(node) if os.environ.get(PUBLICATIONS_ENV) else None
            nodes.append((node, counter))
            executor.add_node(node)
        restart_timers([node for node, _ in nodes])
        _on_stop_signals(request_stop)
        # A bounded wait returns to Python regularly, so the flag is seen even when no timer
        # fires (e.g. on sim time after /clock stopped).
        while rclpy.ok() and not stop.is_set():
            executor.spin_once(timeout_sec=SIGNAL_CHECK_PERIOD)
    except ParameterError as exc:
        print(f'error: {exc}', file=sys.stderr)
        status = 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if not stop.is_set():   # ended otherwise (error, shutdown): bounded all the same
            _exit_hard_after(EXIT_DEADLINE)
        if rclpy.ok():
            shut_down([node for node, _ in nodes])
        for node, counter in nodes:
            if counter is not None:
                counter.save(os.environ[PUBLICATIONS_ENV], node.get_fully_qualified_name())
            node.destroy_node()
        rclpy.try_shutdown()
    return status


LastMessages = Iterable[tuple[Publisher, float]]   # (publisher, s to wait for its acks)


def shut_down(nodes: Sequence[Node]) -> None:
    """Run the nodes' on_shutdown() hooks, then wait for what they sent last to be
    acknowledged. A hook sends its node's last messages and returns the publishers to wait
    for, each with its timeout (s; LastMessages), or None. Every node's last messages go out
    before any wait, and the timeouts count from one start: a process's nodes end in the time
    of their longest wait, not of their sum (a group of 5 controllers took 1.3 s, one 0.25 s
    wait each, for neighbours stopped at the same moment that can no longer acknowledge).
    """
    pending: list[tuple[Publisher, float]] = []
    for node in nodes:
        hook = getattr(node, 'on_shutdown', None)
        if hook is not None:
            pending.extend(hook() or ())
    start = time.monotonic()
    for publisher, timeout in pending:
        left = max(timeout - (time.monotonic() - start), 0.0)
        publisher.wait_for_all_acked(Duration(seconds=left))


def restart_timers(nodes: Sequence[Node]) -> None:
    """Start the nodes' timers' periods as the executor starts, the nodes' phases spread
    evenly over the shortest period: a timer counts from its node's construction, and a
    process building 25 controllers in 0.5 s then fired each one's missed ticks back to back
    (commands 0-6 ms apart) and left gaps of up to 0.5 s; restarted at once, the 25 ticked
    together and waited for each other every period. Takes that period (several nodes).
    """
    timers = [[t for t in node.timers if not t.is_canceled()] for node in nodes]
    periods = [t.timer_period_ns * 1e-9 for node_timers in timers for t in node_timers]
    step = min(periods, default=0.0) / len(nodes) if len(nodes) > 1 else 0.0
    for node_timers in timers:
        for timer in node_timers:
            timer.reset()
        time.sleep(step)


def checked_priority(name: str, value: Any) -> int:
    """`value` of parameter `name` as a SCHED_FIFO priority (scheduling: 0, normal, to 99);
    ParameterError naming the parameter otherwise.
    """
    problem = priority_problem(value)
    if problem:
        raise ParameterError(f'parameter {name!r}: {problem}')
    return value


def _exit_hard_after(seconds: float) -> None:
    """Dump every thread's stack to stderr and end the process if it still runs in `seconds`.

    A node must not outlive its run: Fast DDS has been seen to hang for good while tearing
    down a node whose construction was interrupted. faulthandler's watchdog is a C thread,
    so it fires even while the main thread is blocked in C holding the GIL.
    """
    faulthandler.dump_traceback_later(seconds, exit=True)


def spin_until_quiet(executor: Executor, count: Callable[[], int], quiet: float = 0.3,
                     limit: float = 3.0) -> None:
    """Spin until count() has not changed for `quiet` s, `limit` s at most.

    Takes what already arrived but is still queued (e.g. the last messages for a bag).
    """
    end = time.monotonic() + limit
    quiet_since, seen = time.monotonic(), count()
    while time.monotonic() < end and time.monotonic() - quiet_since < quiet:
        executor.spin_once(timeout_sec=0.02)
        if count() != seen:
            quiet_since, seen = time.monotonic(), count()


def make_executor(context: Optional[Context] = None) -> Executor:
    """The executor chosen by $CURVE_FORMATION_EXECUTOR (default 'events').

    rclpy has the EventsExecutor since Jazzy's 7.1.4; an older rclpy gets the
    SingleThreadedExecutor, with a note on stderr. The EventsExecutor takes SIGINT and SIGTERM
    for itself when it is created (and then shuts the context down on either); the process's
    Python handlers are put back, so that its owner decides how to stop.
    """
    kind = os.environ.get(EXECUTOR_ENV, 'events')
    if kind == 'events':
        try:
            from rclpy.experimental import EventsExecutor
        except ImportError:
            print('note: this rclpy has no EventsExecutor (Jazzy >= 7.1.4); using the '
                  'SingleThreadedExecutor', file=sys.stderr)
            return SingleThreadedExecutor(context=context)
        with _python_signal_handlers_kept():
            return EventsExecutor(context=context)
    if kind == 'single':
        return SingleThreadedExecutor(context=context)
    raise ParameterError(f'environment variable {EXECUTOR_ENV} = {kind!r}; expected one of '
                         f'{", ".join(EXECUTORS)}')


@contextlib.contextmanager
def _python_signal_handlers_kept() -> Iterator[None]:
    if threading.current_thread() is not threading.main_thread():
        yield   # signal handlers can only be set from the main thread
        return
    saved = {sig: signal.getsignal(sig) for sig in STOP_SIGNALS}
    try:
        yield
    finally:
        for sig, handler in saved.items():
            if handler is not None:   # None: not set from Python, cannot be put back
                signal.signal(sig, handler)


class WithMessageInfo:
    """A subscription callback fn(msg, info) that works under both rclpy executors.

    rclpy calls a two-argument callback with the message and its MessageInfo (a dict: source
    and received timestamps in ns, publication_sequence_number, ...). rclpy 7.1.6's
    EventsExecutor passes the pair as one tuple instead, which a plain fn(msg, info) cannot
    take; this object advertises two arguments and accepts either form.
    """

    __signature__ = inspect.Signature([
        inspect.Parameter('msg', inspect.Parameter.POSITIONAL_ONLY),
        inspect.Parameter('info', inspect.Parameter.POSITIONAL_ONLY)])

    def __init__(self, fn: Callable[..., Any]) -> None:
        self.fn = fn

    def __call__(self, *args: Any) -> Any:
        msg, info = args if len(args) == 2 else args[0]
        return self.fn(msg, info)


def _on_stop_signals(handler: Callable[..., Any]) -> None:
    for sig in STOP_SIGNALS:
        signal.signal(sig, handler)
