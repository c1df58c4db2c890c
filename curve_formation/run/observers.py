"""The runner's own ROS context, from which it observes a run: the monitor and, with a bag,
the recorder, spun by one executor (which also hosts a single-process run's nodes).
"""

from contextlib import ExitStack

from curve_formation.bags.analysis import EXPERIMENT_KEY, PARAMETERS_KEY, PROVENANCE_KEY
from curve_formation.nodes.runtime import make_executor, spin_until_quiet


class Observers:
    """A context manager: on entry an rclpy context with the Monitor (nodes/monitor.py) and,
    given an unopened bag.BagWriter, the Recorder writing into it; on exit what is still
    queued is taken, the nodes and context are shut down and the bag is closed.

    experiment_text, parameters_text and provenance_text go into the bag's metadata, so that
    it describes itself (analysis.py). watch False: the monitor takes only the curve (a host
    of a split run that neither measures nor starts the curve server). poses_from_all: the
    monitor reads the robots' poses from /formation/robot_poses (Monitor's).
    """

    def __init__(self, experiment, record_hz, ground_truth, bag_writer=None, images=False,
                 experiment_text='', parameters_text='', watch=True, provenance_text='{}',
                 poses_from_all=False):
        self.experiment = experiment
        self.record_hz = record_hz
        self.ground_truth = ground_truth
        self.bag_writer = bag_writer
        self.images = images
        self.metadata = {EXPERIMENT_KEY: experiment_text, PARAMETERS_KEY: parameters_text,
                         PROVENANCE_KEY: provenance_text}
        self.watch = watch   # False: the monitor only takes the curve (Monitor's watch)
        self.poses_from_all = poses_from_all
        self.context = self.executor = self.monitor = self.recorder = None
        self.best_effort_topics = set()
        self.hosted = []   # a single-process run's nodes, destroyed after the executor stops
        self.finished = False   # finish() has drained and closed the bag
        self._stack = ExitStack()

    def __enter__(self):
        try:
            self._open()
        except BaseException:
            self.__exit__(None, None, None)
            raise
        return self

    def _open(self):
        import rclpy
        from rclpy.context import Context
        from rclpy.signals import SignalHandlerOptions

        from curve_formation.nodes import topics
        from curve_formation.nodes.monitor import Monitor
        from curve_formation.nodes.recorder import Recorder

        self.context = Context()
        # Signals stay with Python (Ctrl-C, or run_experiment's handlers), so that the runner
        # can close the bag and stop the nodes.
        rclpy.init(context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        self._stack.callback(rclpy.try_shutdown, context=self.context)
        recorded = []
        if self.bag_writer is not None:
            self._stack.enter_context(self.bag_writer)
            for key, text in self.metadata.items():
                self.bag_writer.set_custom(key, text)
            recorded = topics.recorded(self.experiment.n, self.images)
            self.best_effort_topics = {t.name for t in recorded if not t.reader_qos.reliable}
        # The same executor as every node process (callbacks dispatched from C++). Python
        # callbacks share the GIL: more executor threads would not run them faster.
        self.executor = make_executor(self.context)
        self.monitor = Monitor(self.experiment.n, self.record_hz, context=self.context,
                               ground_truth=self.ground_truth, watch=self.watch,
                               adoption=len(self.experiment.phases) > 1,
                               experiment=self.experiment, poses_from_all=self.poses_from_all)
        self._stack.callback(self.monitor.destroy_node)
        if recorded:
            self.recorder = Recorder(self.bag_writer, recorded, context=self.context)
            self._stack.callback(self.recorder.destroy_node)
        self._stack.callback(self._destroy_hosted)
        self._stack.callback(self.executor.shutdown, timeout_sec=1.0)   # the first to go
        for node in (self.monitor, self.recorder):
            if node is not None:
                self.executor.add_node(node)

    def __exit__(self, *exc):
        self.finish()
        self._stack.close()   # executor, nodes, context: the reverse of their opening

    def finish(self):
        """Record what is still queued (the nodes' last zero commands among it) and close the
        bag, keeping the ROS entities: what was recorded is whole before DDS lets go of
        anything (letting go can hang: Fast DDS deadlocks at times when an entity is
        destroyed while a remote participant leaves, eProsima/Fast-DDS#6502). Idempotent.
        """
        if self.finished:
            return
        self.finished = True   # nothing is spun after the bag is closed
        if self.executor is not None:
            self.drain()
        if self.bag_writer is not None:
            self.bag_writer.close()

    def _executor(self):
        if self.executor is None:
            raise RuntimeError('the observers are not open (enter them as a context manager)')
        return self.executor

    def add_node(self, node):
        """Spin a node of the run here (single process); it is destroyed on exit."""
        self.hosted.append(node)
        self._executor().add_node(node)

    def _destroy_hosted(self):
        for node in self.hosted:
            node.destroy_node()
        self.hosted = []

    def spin_once(self, timeout=0.02):
        self._executor().spin_once(timeout_sec=timeout)

    def drain(self):
        """Spin until the recorder has taken what already arrived."""
        spin_until_quiet(self._executor(), self.recorded_count)

    def recorded_count(self):
        return 0 if self.bag_writer is None else self.bag_writer.count
