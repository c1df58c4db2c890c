"""Analyse a recorded run from its bag alone: the batch simulator's metrics and figures.

The bag's metadata carries the experiment file (written by `curve-formation run --bag`); the
curves are taken from the recorded /formation/curve messages, so a curve that was observed at
run time is measured too. Poses, commands and estimates are sampled on a uniform grid (latest
value, NaN before the first) from t = 0 at the first curve message, by the live monitor's
sampler (core.record.sampling), which refuses the poses the controllers refuse.
"""

from dataclasses import dataclass, replace
import json
from pathlib import Path
import time

import numpy as np

from curve_formation import diagnostics
from curve_formation.bags.bag import bag_info, bag_summary, BagError, read_messages
from curve_formation.bags.streams import stream_topic
from curve_formation.core.config.agents import geofence
from curve_formation.core.config.experiment import phase_index
from curve_formation.core.config.loading import (
    build_experiment,
    control_rate,
    load_experiment,
    parse_experiment_text,
)
from curve_formation.core.controller.estop import stopped_intervals
from curve_formation.core.formation.curve_codec import CodecError
from curve_formation.core.record import metrics
from curve_formation.core.record.received_phases import received_phases
from curve_formation.core.record.sampling import GridSampler, LatestValues
from curve_formation.figures import plots
from curve_formation.interface import (
    agent_parameters_from_msg,
    CMD_VEL,
    CURVE,
    curve_clock_from_msg,
    curve_from_msg,
    DIAGNOSTICS,
    ESTIMATE,
    ESTOP_STATE,
    estop_state_from_msg,
    POSE,
    pose_from_msg,
    robot_of,
    twist_from_msg,
    type_name,
)
from curve_formation.paths import resolve_config
from curve_formation.results.outputs import write_outputs


# Keys of the bag metadata (custom_data) that make a bag self-describing: the experiment file
# and every node's parameters file.
EXPERIMENT_KEY = 'curve_formation.experiment'
PARAMETERS_KEY = 'curve_formation.parameters'
# When the run ended (ns, the recorder's clock), before its nodes were stopped: what they do
# while stopping is not the run.
RUN_END_KEY = 'curve_formation.run_end_ns'
PROVENANCE_KEY = 'curve_formation.provenance'   # JSON: provenance.provenance() of the run
# The per-robot topics the analysis samples (interface names).
SAMPLED = (POSE, CMD_VEL, ESTIMATE)


@dataclass
class BagRun:
    """A run read from a bag: the experiment (phases from the bag's curves) and series."""

    experiment: object
    t: np.ndarray          # (R,) s since the first curve
    poses: np.ndarray      # (R, n, 3)
    commands: np.ndarray   # (R, n, 2)
    dhat: np.ndarray       # (R, n, 2)
    phase: np.ndarray      # (R,)
    counts: dict           # {topic: messages read}
    contacts: dict | None = None  # fake_arena's last contact report, if the bag has one
    estops: list | None = None    # [(start, stop or None)] s while a node held the e-stop
    deaths: list | None = None    # [(t s, node, how)] nodes of the run that died
    pose_stamps: np.ndarray | None = None   # (R, n) s since t = 0: when each pose was taken
    provenance: dict | None = None   # of the run that wrote the bag (provenance.py), if told
    experiment_text: str | None = None   # the experiment as the bag carries it (or the file's)


PROGRESS_PERIOD = 2.0   # s between progress lines while a bag is read


def load_bag_run(path, experiment_path=None, sample_hz=20.0, progress=None):
    """Read a bag into a BagRun; BagError with a clear message if it cannot be used.

    progress: called with a line ('read 120000 of 500000 messages (24 %)') every
    PROGRESS_PERIOD s while the bag is read.
    """
    path = Path(path)
    topics, custom = bag_info(path)
    for topic, (msgtype, _) in topics.items():
        # the message type each topic the analysis reads must have (another tool's may differ)
        wanted = type_name(topic) if topic == CURVE or robot_of(topic, SAMPLED) else None
        if wanted is not None and msgtype != wanted:
            raise BagError(f'{path}: {topic} holds {msgtype}, expected {wanted}: not a '
                           "bag of this package's run (record one with `curve-formation run "
                           '--bag`)')
    if experiment_path is not None:
        experiment = load_experiment(resolve_config(experiment_path))
        experiment_text = resolve_config(experiment_path).read_text()
    elif EXPERIMENT_KEY in custom:
        experiment_text = custom[EXPERIMENT_KEY]
        source = f'{path} (metadata)'
        experiment = build_experiment(parse_experiment_text(custom[EXPERIMENT_KEY], source),
                                      source)
    else:
        raise BagError(f'{path}: the bag does not carry its experiment; pass --experiment')
    n = experiment.n
    # each robot's latest values, sampled from the first curve on as the live monitor does
    latest = LatestValues(n, geofence(experiment))
    sampler = GridSampler(latest, sample_hz)
    last_pose = None   # when the last pose was received (s)
    curves: list = []
    counts: dict[str, int] = {}
    contacts = None
    estop_events: list = []
    death_events: list = []
    read = [topic for topic in topics if topic in (ESTOP_STATE, DIAGNOSTICS, CURVE)
            or robot_of(topic, SAMPLED)]   # a topic of another tool may be of any type
    total, done, said = sum(topics[topic][1] for topic in read), 0, time.monotonic()
    for topic, _, stamp, msg in read_messages(path, read):
        counts[topic] = counts.get(topic, 0) + 1
        done += 1
        if progress is not None and time.monotonic() - said >= PROGRESS_PERIOD:
            said = time.monotonic()
            progress(f'read {done} of {total} messages ({100 * done / max(total, 1):.0f} %)')
        t = stamp * 1e-9
        sampler.until(t)   # the rows due before this message
        if topic == ESTOP_STATE:
            try:
                report = estop_state_from_msg(msg)
            except (CodecError, AttributeError):
                continue
            estop_events.append((t, report.holder, report.engaged))
            continue
        if topic == DIAGNOSTICS:
            for status in msg.status:
                values = {kv.key: kv.value for kv in status.values}
                if status.hardware_id == diagnostics.CONTACT_REPORTER:
                    contacts = diagnostics.contacts_from_report(values)
                elif status.hardware_id == diagnostics.NODE_DEATH_REPORTER:
                    death_events.append((t, values.get('node', '?'), values.get('how', '?')))
            continue
        if topic == CURVE:
            curve, curve_id = curve_from_msg(msg)
            s = agent_parameters_from_msg(msg)
            if s is None or len(s) != n:
                raise BagError(f"{path}: curve {curve_id} carries no agents' parameters for "
                               f'{n} agents: cannot tell which robot goes where')
            if not curves:
                sampler.start(t)   # t = 0
            curves.append((t, curve_id, curve, s, curve_clock_from_msg(msg)))
            continue
        placed = robot_of(topic, SAMPLED)
        if placed is None or not 1 <= placed[0] <= n:
            continue
        robot, kind = placed
        if kind == POSE:
            last_pose = t
            try:
                latest.pose(robot, *pose_from_msg(msg))
            except CodecError:   # not a pose: the monitor does not take it either
                pass
        elif kind == CMD_VEL:
            latest.command(robot, *twist_from_msg(msg))
        else:
            latest.estimate(robot, msg.vector.x, msg.vector.y)
    if not curves:
        raise BagError(f'{path}: no /formation/curve message: nothing to measure against')
    t0 = curves[0][0]
    end = t0 if last_pose is None else max(last_pose, t0)
    if RUN_END_KEY in custom:
        end = min(end, int(custom[RUN_END_KEY]) * 1e-9)
    if end - t0 < 2.0 / sample_hz:
        raise BagError(f'{path}: less than two samples of poses after the first curve')
    record = sampler.finish(end)
    phases = received_phases(experiment, [(t - t0, k, curve, s, None if clock is None
                                           else clock.since(t0))
                                          for t, k, curve, s, clock in curves])
    estops = stopped_intervals([(t - t0, holder, engaged)
                                for t, holder, engaged in estop_events], end - t0)
    return BagRun(replace(experiment, phases=phases), record['t'], record['poses'],
                  record['commands'], record['dhat'],
                  phase_index([p.start for p in phases], record['t']), counts, contacts,
                  estops, [(t - t0, node, how) for t, node, how in death_events],
                  record['pose_stamps'], _run_provenance(custom), experiment_text)


def _run_provenance(custom):
    try:
        return json.loads(custom[PROVENANCE_KEY])
    except (KeyError, ValueError):
        return None   # a bag of an older version, or of another tool


def analyze_bag(path, out_dir, experiment_path=None, compare=None, compare_sim=False,
                progress=None, animate=False):
    """The run's folder from a bag (outputs.write_outputs: metrics.json, the paper's figures,
    trajectory.npz, report.html; animation.mp4 if `animate`); `compare` overlays a second
    run (a bag, or a folder of `sim`, `run` or `analyze`), `compare_sim` the batch simulator
    run from the bag's own start (simulate_recorded).
    progress: called with a line on what is being done (load_bag_run).
    """
    run = load_bag_run(path, experiment_path, progress=progress)
    t, poses, phase, dhat, commands = known_samples(run, path)
    stamps = run.pose_stamps[len(run.t) - len(t):]
    result = metrics.run_metrics(run.experiment, t, poses, phase, np.nan_to_num(dhat),
                                 np.nan_to_num(commands), contacts=run.contacts,
                                 estops=run.estops, deaths=run.deaths, stamps=stamps)
    result['node_deaths'] = [{'node': node, 't': t, 'how': how} for t, node, how in run.deaths]
    result['bag'] = {'path': str(path), 'messages': run.counts}
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    others = []
    if compare is not None:
        _, o_t, o_poses, o_phase = load_run(compare, experiment_path)   # a bag or a folder
        result['compare'] = metrics.run_metrics(run.experiment, o_t, o_poses, o_phase)
        others.append((Path(compare).name, o_t, o_poses, o_phase))
    if compare_sim:
        if progress is not None:
            progress("simulating the bag's start and curves (--compare-sim)")
        sim = simulate_recorded(run.experiment, t, poses)
        result['compare_sim'] = metrics.result_metrics(sim)
        result['compare_sim_table'] = settling_table(result, result['compare_sim'])
        others.append(('simulated', sim.t, sim.poses, sim.phase))
    # this run's error norm, once, measured as its metrics are (each pose at its stamp)
    own = (metrics.error_norm(metrics.target_errors(poses, phase, run.experiment, t=t,
                                                    stamps=stamps)) if others else None)
    for label, o_t, o_poses, o_phase in others:
        stem = 'compare' if label != 'simulated' else 'compare_sim'
        other = metrics.error_norm(metrics.target_errors(o_poses, o_phase, run.experiment,
                                                         t=o_t))
        plots.plot_error_norm(out / f'{stem}_error_norm.png', run.experiment,
                              [(Path(path).name, t, own), (label, o_t, other)])
        plots.plot_paths(out / f'{stem}_paths.png', run.experiment, poses, phase,
                         overlay=(label, o_poses))
    result['run_provenance'] = run.provenance
    write_outputs(out, run.experiment, {'t': t, 'poses': poses, 'phase': phase,
                                        'dhat': np.nan_to_num(dhat), 'commands': commands,
                                        'pose_stamps': stamps},
                  result, experiment_path, label=Path(path).name,
                  experiment_text=run.experiment_text, animate=animate)
    return result


def known_samples(run, path):
    """(t, poses, phase, dhat, commands) from the first sample at which every robot's pose is
    known; BagError if there is none.
    """
    usable = ~np.isnan(run.poses).any(axis=(1, 2))
    if not usable.any():
        raise BagError(f"{path}: no time at which every robot's pose is known")
    first = np.argmax(usable)
    return (run.t[first:], run.poses[first:], run.phase[first:], run.dhat[first:],
            run.commands[first:])


def simulate_recorded(experiment, t, poses):
    """The batch simulator (the nodes' tick pipeline for settings only it models:
    pipeline.simulate_kinematic) on a recorded run's experiment (its phases as
    the run received them: curves, agents' parameters and switch times) from the run's first
    known poses (t[0], poses[0]); returns a SimResult whose t is on the run's clock (s since
    t = 0).
    """
    from curve_formation.core.sim.pipeline import simulate_kinematic
    begin = float(t[0])
    # A phase that began before the first known poses starts the simulation.
    start_phase = max(0, int(np.searchsorted([p.start for p in experiment.phases], begin,
                                             side='right')) - 1)
    shifted = tuple(replace(p, start=max(0.0, p.start - begin), changes=())
                    for p in experiment.phases[start_phase:] if p.start < t[-1])
    shifted = (replace(shifted[0], start=0.0),) + shifted[1:]
    sim_experiment = replace(experiment, phases=shifted, initial_poses=np.array(poses[0]))
    spec = experiment.spec.simulation
    duration = float(t[-1] - begin)
    duration = round(duration / spec.record_dt) * spec.record_dt
    result, _ = simulate_kinematic(sim_experiment, control_rate(experiment), duration)
    result.t = result.t + begin
    result.phase = result.phase + start_phase
    # The simulation's own re-assignments, on the run's clock.
    followed = tuple(replace(real, changes=tuple((when + begin, s, points)
                                                 for when, s, points in simulated.changes))
                     for real, simulated in zip(experiment.phases[start_phase:],
                                                result.experiment.phases, strict=False))
    result.experiment = replace(experiment, phases=experiment.phases[:start_phase] + followed
                                + experiment.phases[start_phase + len(followed):])
    return result


def settling_table(real, simulated):
    """Per phase: settling time and final error of a recorded run and of its simulation."""
    rows = []
    sims = {p['index']: p for p in simulated['phases']}
    for p in real['phases']:
        other = sims.get(p['index'], {})
        rows.append({'phase': p['index'], 'start': p['start'],
                     'settle_time': p['settle_time'], 'settle_time_sim': other.get('settle_time'),
                     'final_error_norm': p['final_error_norm'],
                     'final_error_norm_sim': other.get('final_error_norm')})
    return rows


def bag_accounting(bag_path, publications_dir, streams, best_effort=()):
    """Per recorded topic: messages the nodes published, should have recorded, and recorded.

    A DDS writer numbers its samples 1, 2, ... in publish order, so a writer stream (see
    streams.stream_key) of N publications whose first received sample was number f should have
    put N - f + 1 in the bag, however late the recorder was matched. `streams` is the
    recorder's tally (Recorder.streams). A stream never received counts whole, and so does
    one with several writers or out of order. `lost`: expected but not in the bag, summed over
    the reliable topics; `lost_best_effort`: the same over the `best_effort` topics (poses,
    images), whose samples DDS may drop by design.
    """
    published: dict[str, int] = {}
    writers: dict[str, int] = {}
    for path in Path(publications_dir).glob('*.json'):
        for key, count in json.loads(path.read_text()).items():
            published[key] = published.get(key, 0) + count
            writers[key] = writers.get(key, 0) + 1
    recorded = {topic: count for topic, (_, count) in bag_summary(bag_path).items()}

    topics = {t: {'published': 0, 'expected': 0, 'recorded': n, 'lost': 0,
                  'best_effort': t in best_effort} for t, n in sorted(recorded.items())}
    for key, count in published.items():
        name = stream_topic(key)
        if name not in recorded:   # a topic the bag does not record, e.g. RViz markers
            continue
        stream = streams.get(key, {'first': 1, 'received': 0, 'in_order': True})
        exact = writers[key] == 1 and stream['in_order']
        expected = count - stream['first'] + 1 if exact else count
        topic = topics[name]
        topic['published'] += count
        topic['expected'] += expected
        topic['lost'] += max(0, expected - stream['received'])
    for name, topic in topics.items():   # received but not written: the bag writer failed
        received = sum(s['received'] for s in streams.values() if s['topic'] == name)
        topic['lost'] += max(0, received - topic['recorded'])

    def lost(effort):
        return sum(v['lost'] for v in topics.values() if v['best_effort'] == effort)
    return {'topics': topics, 'lost': lost(False), 'lost_best_effort': lost(True),
            'published': sum(v['published'] for v in topics.values())}


def load_run(source, experiment_path=None):
    """(experiment, t, poses, phase) of a run's folder (trajectory.npz and experiment.yaml, as
    write_outputs leaves them) or of a bag. experiment_path: the experiment, where the folder
    or the bag does not carry it. ValueError naming the source when it is neither.
    """
    source = Path(source)
    trajectory = source / 'trajectory.npz'
    if trajectory.exists():
        path = (resolve_config(experiment_path) if experiment_path is not None
                else source / 'experiment.yaml')
        if not path.exists():
            raise ValueError(f'{source}: no experiment.yaml beside trajectory.npz; pass '
                             '--experiment FILE')
        record = np.load(trajectory)
        return load_experiment(path), record['t'], record['poses'], record['phase']
    if (source / 'metadata.yaml').exists() or any(source.glob('*.mcap')) or any(
            source.glob('*.db3')):
        run = load_bag_run(source, experiment_path)
        t, poses, phase, _, _ = known_samples(run, source)
        return run.experiment, t, poses, phase
    raise ValueError(f'{source}: neither a run folder (trajectory.npz) nor a ROS 2 bag')
