"""`curve-formation run` to its end: an experiment's node graph (runner.Run) run for its
duration, stopped on Ctrl-C or SIGTERM, and its results written (metrics.json, figures, the
bag's accounting), also after an error of the runner itself.
"""

import signal

from curve_formation.results.outputs import write_outputs
from curve_formation.run.launches import held_robots
from curve_formation.run.run_options import DEFAULTS
from curve_formation.run.run_record import STATUS_PERIOD
from curve_formation.run.runner import Run


# s a host without the observer keeps its nodes up after the run's duration (split runs)
SPLIT_GRACE = 10.0


def run_experiment(config, out_dir, duration=None, options=DEFAULTS, log=print):
    """Run an experiment's node graph for `duration` s (default: the file's) and measure it.

    Ctrl-C (SIGINT) and SIGTERM stop every node and close the bag; both only set
    Run.stop_requested, acted on between callbacks (see Run.spin_until). A node that dies
    does not end the run (Run._on_death; result['node_deaths']). An unexpected error of the
    runner itself still stops the nodes, closes the bag and writes what was measured (with
    result['runner_error']) before it is raised again.
    """
    run = Run(config, out_dir, options, log)
    duration = run.experiment.spec.simulation.duration if duration is None else duration
    if not options.runs('observer'):   # outlast the host that measures, which stops us
        duration += SPLIT_GRACE
    previous = {sig: signal.signal(sig, lambda *_: run.stop_requested.set())
                for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        return _run_and_measure(run, duration, options, log)
    finally:
        run.stop()   # after the results are written: letting go of DDS can hang
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def _run_and_measure(run, duration, options, log):
    """run_experiment's run, then its results written (the nodes stopped and the bag closed
    in between, Run.wind_down).
    """
    interrupted = False
    failure = None
    started = False
    try:
        run.start()
        started = True
        run.spin_for(duration, STATUS_PERIOD)
    except KeyboardInterrupt:
        interrupted = True
        log('interrupted: stopping every node')
    except Exception as exc:  # noqa: BLE001 - written down below, then raised again
        if not started:
            raise
        failure = exc
        log(f'error in the runner: {type(exc).__name__}: {exc}; stopping every node and '
            'writing what was measured')
    finally:
        run.wind_down()
    if not options.runs('observer'):
        return {'experiment': run.experiment.name, 'interrupted': interrupted,
                'parts': sorted(options.only or ())}
    try:
        experiment, record, result = run.measure()
    except RuntimeError:
        if failure is None:
            raise
        raise failure from None   # nothing recorded: the runner's error is what matters
    result['interrupted'] = interrupted
    result['node_deaths'] = [{'node': key, 't': t, 'how': how, 'robots': held_robots(key)}
                             for t, key, how in run.monitor.node_deaths]
    if failure is not None:
        result['runner_error'] = f'{type(failure).__name__}: {failure}'
    if options.bag_path is not None:
        assert run.bag_writer is not None   # a run with a bag_path writes one
        result['bag'] = {'path': str(options.bag_path), 'messages': run.bag_writer.count,
                         **run.bag_accounting()}
    write_outputs(run.out, experiment, record, result, run.experiment_path, label='ROS run',
                  animate=options.animate)
    if failure is not None:
        raise failure
    return result
