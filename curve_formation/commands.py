"""What each `curve-formation` subcommand does, from its parsed arguments (cli.py parses
them and turns errors into one line): check, sim, demo, run, params, analyze, animate,
measure-link, bag info and repair, replay, discovery-server, clean-shm, estop, preflight,
calibrate-camera, nodes-doc. Each returns the exit status (None: 0).
"""

import json
import os
from pathlib import Path
import sys

from curve_formation.core.config.loading import load_experiment
from curve_formation.paths import resolve_config
from curve_formation.workflows import (
    run_demo,
    simulate_to_dir,
    summary_line,
    warn,
    write_json,
)


# `run`'s exit status when a node of the run died (the run went on and wrote its results).
EXIT_NODE_DIED = 3


def cmd_check(args):
    from curve_formation.core.config.agents import leader_relays
    from curve_formation.fleet import fleet_robots
    from curve_formation.vision.camera_files import check_camera_files
    experiment = load_experiment(resolve_config(args.config))
    warn(experiment)
    report = experiment.report()
    report['camera_files'] = check_camera_files(experiment)
    report['fleet'] = [{'robot': r.agent, 'marker': r.marker, 'link': r.address.text,
                        'baud': r.address.baud, 'format': r.format}
                       for r in fleet_robots(experiment)]
    if args.json:
        print(json.dumps(report, indent=2))
        return
    print(f'{report["experiment"]}: {report["agents"]} agents, leader {report["leader"]}, '
          f'{len(report["edges"])} edges; rooted spanning tree: yes')
    t1 = report['theorem1']
    print(f'Theorem 1: P, Q positive definite (min eig {t1["min_eig_P"]:.3g}, '
          f'{t1["min_eig_Q"]:.3g}); slowest mode of L+B: '
          f'{report["slowest_mode_of_L_plus_B"]:.3g}')
    for k, c in enumerate(report['curves']):
        print(f'curve {k} from t = {c["start"]:g} s: {c["basis"]}, fit rms residual '
              f'{c["fit_rms_residual"]:.2g} over {c["samples"]} samples, rank G_bar '
              f'{c["rank_G_bar"]}, n <= H: {c["n_le_H"]}')
        print('    s_i = ' + ', '.join(f'{v:.4f}' for v in c['s']))
    for line in report['camera_files']:
        print(line)
    relays = leader_relays(experiment)
    deepest = int(relays.argmax())
    if relays[deepest] > 0.0:
        timeout = experiment.spec.safety.leader_timeout
        hops = int(experiment.graph.hops_from_leader()[deepest])
        print(f"leader's news: robot {deepest + 1} is {hops} hops from the leader, relayed "
              f'with each pose: it stops after {timeout:g} s + {relays[deepest]:.2f} s without '
              'news (safety.leader_timeout, plus a pose period and delivery a hop)')
    for robot in report['fleet']:
        baud = f' at {robot["baud"]} baud' if robot['link'].startswith('serial:') else ''
        print(f'robot {robot["robot"]}: {robot["link"]}{baud}, {robot["format"]}, marker '
              f'{robot["marker"] if robot["marker"] is not None else "(none)"}')


def cmd_sim(args):
    rate: str | float | None = 'config'
    if args.continuous:
        rate = None
    elif args.rate is not None:
        rate = args.rate
    _output_folder(args.out, args.force)
    data = simulate_to_dir(args.config, args.out, rate, args.law, args.heading, args.physics,
                           args.animate)
    print(summary_line(data['experiment'], data))
    print(f"simulated by: {data['simulator']}")   # the batch simulator, or why not
    print(f'wrote {args.out}/: report.html, metrics.json, figures (PNG and PDF), '
          f'trajectory.npz{", animation.mp4" if args.animate else ""}')


def cmd_demo(args):
    out = Path(args.out)
    _output_folder(out)
    run_demo(out, args.duration)


def cmd_run(args):
    from curve_formation.run.run_experiment import run_experiment
    from curve_formation.run.run_options import RunOptions
    _bridge_needs_simulated_robots(args)
    warn(load_experiment(resolve_config(args.config)))
    only = _parts(args.only)
    _output_folder(args.out, args.force)
    options = RunOptions(single_process=args.single_process, with_robots=not args.no_sim,
                         rate_hz=args.rate, bag_path=args.bag,
                         camera={} if args.camera else None, bag_images=args.bag_images,
                         bag_storage=args.bag_storage, bridge=args.bridge,
                         discovery_server=args.discovery_server, only=only,
                         agents=_agents(args.agents), isolated=args.isolated,
                         physics=args.physics, animate=args.animate,
                         preflight=not args.no_preflight,
                         controllers_per_process=args.controllers_per_process,
                         realtime_priority=args.realtime_priority,
                         allow_missing=frozenset(_agents(args.allow_missing, '--allow-missing')
                                                 or ()))
    result = run_experiment(args.config, args.out, args.duration, options)
    if not options.runs('observer'):
        print(f'ran {", ".join(sorted(only or ()))} of {result["experiment"]}; logs/ in '
              f'{args.out} (the host with `observer` writes the metrics)')
        return
    print(summary_line(result['experiment'], result))
    print(f'wrote {args.out}/: report.html, metrics.json, figures, params/ and logs/')
    if result['node_deaths']:
        died = ', '.join(f'{d["node"]} ({d["how"]})' for d in result['node_deaths'])
        print(f'error: nodes died during the run: {died}; metrics.json says when',
              file=sys.stderr)
        return EXIT_NODE_DIED


def _bridge_needs_simulated_robots(args):
    if args.bridge and args.no_sim:
        raise ValueError('--bridge drives emulated robots and --no-sim has none; real '
                         "robots' bridges start from the file's robots.fleet "
                         '(docs/arena-setup.md)')


def cmd_params(args):
    from curve_formation.run.run_options import RunOptions
    from curve_formation.run.start_scripts import graph_launches, write_node_files
    _bridge_needs_simulated_robots(args)
    path = resolve_config(args.config)
    out = _output_folder(args.out, args.force)
    observed = args.observer or args.bag is not None
    experiment, launches = graph_launches(path, out, not args.no_sim, args.camera, args.bridge,
                                          args.rate, args.bag, observed, args.physics,
                                          args.controllers_per_process,
                                          args.realtime_priority)
    run_args = None
    if observed:
        run_args = [str(path)] + (['--rate', f'{args.rate:g}'] if args.rate else []) \
            + (['--no-sim'] if args.no_sim else []) + (['--camera'] if args.camera else []) \
            + (['--bridge', args.bridge] if args.bridge else []) \
            + (['--physics', args.physics] if args.physics else []) \
            + (['--bag', str(Path(args.bag).resolve())] if args.bag else [])
    size = RunOptions(controllers_per_process=args.controllers_per_process).group_size(
        experiment.n)
    params, scripts = write_node_files(launches, out, experiment.name, run_args, size)
    print(f'wrote {len(params)} parameters files in {out / "params"} and start scripts:')
    for script in scripts:
        print(f'  {script}')
    print('start each part on the host that runs it, every host on the same ROS_DOMAIN_ID '
          f'(e.g. `ROS_DOMAIN_ID=42 {out / "start_all.sh"}`)')


def _agents(text, flag='--agents'):
    """The frozenset of agents `flag` names ('1-5,9'), or None for every agent."""
    if text is None:
        return None
    agents: set[int] = set()
    try:
        for item in text.split(','):
            low, _, high = item.strip().partition('-')
            agents.update(range(int(low), int(high or low) + 1))
    except ValueError:
        raise ValueError(f'{flag}: expected agent numbers and ranges such as 1-5,9, got '
                         f'{text!r}') from None
    if not agents or min(agents) < 1:
        raise ValueError(f'{flag}: expected agent numbers from 1, got {text!r}')
    return frozenset(agents)


def _parts(text):
    """The frozenset of graph parts `--only` names, or None for the whole graph."""
    from curve_formation.run.run_options import PARTS
    if text is None:
        return None
    parts = frozenset(p.strip() for p in text.split(',') if p.strip())
    unknown = sorted(parts - set(PARTS))
    if unknown or not parts:
        raise ValueError(f'--only: unknown part(s) {unknown or [text]}; choose from '
                         f'{", ".join(PARTS)} (comma-separated)')
    if not os.environ.get('ROS_DOMAIN_ID'):
        raise ValueError('--only: set the same ROS_DOMAIN_ID on every host of a split run')
    return parts


def cmd_analyze(args):
    from curve_formation.bags.analysis import analyze_bag
    _output_folder(args.out, args.force)
    result = analyze_bag(args.bag, args.out, args.experiment, args.compare, args.compare_sim,
                         progress=lambda line: print(line, file=sys.stderr, flush=True),
                         animate=args.animate)
    print(summary_line(result['experiment'], result))
    if args.compare_sim:
        print(summary_line('simulated', result['compare_sim']))
        print(f'{"phase":>5s} {"start (s)":>9s} {"settled (s)":>12s} {"simulated (s)":>14s} '
              f'{"final ||e||":>12s} {"simulated":>10s}')
        for row in result['compare_sim_table']:
            print(f'{row["phase"]:5d} {row["start"]:9.2f} {_seconds(row["settle_time"]):>12s} '
                  f'{_seconds(row["settle_time_sim"]):>14s} {row["final_error_norm"]:12.3g} '
                  f'{_number(row["final_error_norm_sim"]):>10s}')
    print(f'wrote {args.out}/: report.html, metrics.json, figures (PNG and PDF), '
          f'trajectory.npz{", animation.mp4" if args.animate else ""}')


def cmd_animate(args):
    from curve_formation.bags.analysis import load_run
    from curve_formation.figures.animation import animate
    out = Path(args.out)
    if out.exists() and not args.force:
        raise ValueError(f'{out} exists: choose another --out, or --force to replace it')
    experiment, t, poses, phase = load_run(args.source, args.experiment)
    view = None
    if args.camera:
        from curve_formation.vision.render import camera_view
        view = camera_view(experiment, (960, 540))
    frames = animate(out, experiment, t, poses, phase, fps=args.fps,
                     max_seconds=args.max_seconds, camera_view=view)
    print(f'wrote {out}: {frames} frames of {experiment.name} ({t[-1] - t[0]:.1f} s of run)')


def cmd_measure_link(args):
    from curve_formation.bags.measure_link import measure_bag
    from curve_formation.core.controller.wheel_estimate import GAIN_ERROR
    found = measure_bag(args.bag, args.motor_time_constant)
    estimated = found['motor_estimated']
    if not estimated and found['motor_time_constant'] > 0:
        print(f"the commands taken through the motors' {_ms(found['motor_time_constant'])} ms "
              'lag (limits.motor_time_constant)')
    print(f'{"robot":>5s} {"latency (ms)":>12s} {"spread (ms)":>11s} {"windows":>7s} '
          f'{"commands":>8s} {"poses":>6s}' + (f' {"motor lag (ms)":>14s}' if estimated
                                                 else '') + f' {"wheel gains (l, r)":>30s}'
          + f' {"dead band (mm/s)":>16s}')
    for i, row in found['robots'].items():
        told = row['latency'] is not None
        gains, errors, band = row['wheel_gains'], row['wheel_gain_errors'], row['dead_band']
        band_text = _mm(band) + ('' if band is None else f' +- {_mm(row["dead_band_bound"])}')
        print(f'{i:5d} {_ms(row["latency"]):>12s} {_ms(row["spread"]):>11s} '
              f'{row["windows"]:7d} {row["commands"]:8d} {row["poses"]:6d}'
              + (f' {_ms(row["motor_time_constant"]):>14s}' if estimated else '')
              + f' {_gains(gains, errors):>30s}'
              + f' {band_text:>16s}'
              + ('' if told else '  (its commands hardly changed: nothing to time)'))
    for i, row in found['robots'].items():
        check = row['check']
        if check is not None:
            band = check['dead_band']
            errors = check['gain_errors']
            print(f'robot {i} motor check (controller.motor_check): wheel gains '
                  f'{check["wheel_gains"][0]:.3f}, {check["wheel_gains"][1]:.3f}'
                  + ('' if errors is None else
                     f' +- {errors[0]:.3f}, {errors[1]:.3f}'
                     + ('' if check['used'] else f' (not used: over {GAIN_ERROR:g})'))
                  + '; dead band '
                  + ('-' if band is None else f'{_mm(band)} +- {_mm(check["bound"])} mm/s')
                  + (f'; {check["repeated"]} stage(s) run again (a gap in poses or ticks)'
                     if check['repeated'] else ''))
    if found['latency'] is None:
        print('no robot told its latency: record a run in which the robots drive')
        return 1
    print('spread: how much the latency of 4 s windows varies (the jitter, and the '
          "estimate's own noise); wheel gains: each wheel's speed per unit of command +- "
          "3 standard errors, - where the commands did not tell it (within 1 %) or the "
          "experiment gives no wheel base; dead band +- its fit's bound")
    print(f'to tell the controllers (the median over the robots, s):\ncontroller: '
          f'{{command_latency: {max(found["latency"], 0.0):.3f}, estimate_latency: false}}\n'
          '(with estimate_latency: true they estimate it online, starting from '
          'command_latency)')
    if estimated and found['motor_time_constant'] is not None:
        print("the motors' lag, fitted with the latency (the median over the robots, s):\n"
              f'limits: {{motor_time_constant: {found["motor_time_constant"]:.3f}}}\n'
              '(or controller: {estimate_motors: true} to estimate it online)')
    if found['dead_band'] is not None:
        print("the motors' dead band, the smallest wheel command that turns a wheel (the median "
              "over the robots, each its motor check's where that is used, m/s):"
              f'\nlimits: {{min_wheel_speed: {found["dead_band"]:.5f}}}\n'
              '(or controller: {motor_check: true} to measure it as each run begins)')
    _print_own(found)
    if args.json:
        write_json(Path(args.json), found)
    return 0


def _print_own(found):
    """measure-link's lines for each robot's own dead band: the bag's robots.fleet with it
    put in, or, where it lists none, one line per robot.
    """
    import yaml

    from curve_formation.bags.measure_link import fleet_with_own, own_settings
    own = own_settings(found)
    if not own:
        return
    fleet = fleet_with_own(found)
    print("or each robot's own dead band (its entry in robots.fleet wins over limits):")
    if fleet is None:
        for i, settings in own.items():
            print(f'robot {i}: ' + yaml.safe_dump(settings, default_flow_style=True,
                                                  sort_keys=False).strip())
        return
    print('robots:\n  fleet:')
    for entry in fleet:
        print('    - ' + yaml.safe_dump(entry, default_flow_style=True, sort_keys=False,
                                        width=1000).strip())


def _ms(value):
    return '-' if value is None else f'{1000 * value:.1f}'


def _gains(gains, errors):
    """Wheel gains (left, right) +- GAIN_BOUND standard errors, as the controllers report
    them (RobotModel.estimates); '-' for none.
    """
    from curve_formation.core.controller.robot_model import GAIN_BOUND
    if gains is None:
        return '-'
    return (f'{gains[0]:.3f}, {gains[1]:.3f}' if errors is None else
            f'{gains[0]:.3f}, {gains[1]:.3f} +- {GAIN_BOUND * errors[0]:.3f}, '
            f'{GAIN_BOUND * errors[1]:.3f}')


def _mm(value):
    return '-' if value is None else f'{1000 * value:.2f}'


def _seconds(value):
    return 'not settled' if value is None else f'{value:.2f}'


def _number(value):
    return '-' if value is None else f'{value:.3g}'


def cmd_bag_info(args):
    from curve_formation.bags.bag import describe_bag, format_bag_info
    info = describe_bag(args.bag)
    print(json.dumps(info, indent=2) if args.json else format_bag_info(info))


def cmd_bag_repair(args):
    from curve_formation.bags.bag import repair
    out, count = repair(args.bag, args.out)
    print(f'wrote {out}: {count} messages')


def cmd_replay(args):
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    from curve_formation.bags.replay import replay
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node('bag_replay')
    try:
        sent = replay(node, args.bag, args.rate, args.topics, args.loop, args.start,
                      clock=not args.no_clock, wait_for_subscribers=args.wait)
        print(f'replayed {sent} messages')
    except KeyboardInterrupt:
        print('replay interrupted')
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


def cmd_discovery_server(args):
    from curve_formation.paths import discovery_server_command
    argv, env = discovery_server_command(args.address, args.port)
    os.execve(argv[0], argv, env)


def cmd_clean_shm(args):
    """Fast DDS's `fastdds shm clean` (segments and ports whose lock nobody holds), then
    the port files it leaves (dds_shm): what processes killed hard left in /dev/shm. Files a
    live process holds are kept.
    """
    from curve_formation.dds_shm import clean
    status, removed = clean()   # without the tool, FileNotFoundError: main's error line
    print(f'{len(removed)} port files without a lock or a user removed')
    return status


def cmd_estop(args):
    from curve_formation.run.estop_command import send_estop
    expect = args.expect
    if args.experiment is not None:
        expect = load_experiment(resolve_config(args.experiment)).n
    return send_estop(args.state == 'on', expect, args.wait, args.hold)


def cmd_preflight(args):
    from curve_formation.fleet import fleet_robots
    from curve_formation.run.preflight import preflight_command
    experiment = load_experiment(resolve_config(args.config))
    result = preflight_command(experiment, fleet_robots(experiment),
                               frozenset(_agents(args.allow_missing, '--allow-missing') or ()))
    if args.json:
        write_json(Path(args.json), result.as_dict())


def cmd_calibrate_camera(args):
    from curve_formation.vision.intrinsics import (
        BoardSpec,
        calibrate,
        read_images,
        write_intrinsics,
    )
    spec = BoardSpec(tuple(args.squares), args.square_size, args.marker_size, args.dictionary)
    if spec.marker_size >= spec.square_size:
        raise ValueError(f'--marker-size ({spec.marker_size:g} m) must be smaller than '
                         f'--square-size ({spec.square_size:g} m)')
    result = calibrate(read_images(args.source, args.every, args.limit), spec, args.max_rms,
                       args.min_views)
    write_intrinsics(args.out, result)
    k = result.camera_matrix
    print(f'{result.views} views, reprojection RMS {result.rms:.3f} px; focal {k[0, 0]:.1f} x '
          f'{k[1, 1]:.1f} px, centre ({k[0, 2]:.1f}, {k[1, 2]:.1f}) px, distortion '
          f'{" ".join(f"{v:.4g}" for v in result.distortion)}')
    print(f'wrote {args.out} (camera.intrinsics_file of an experiment)')


def cmd_nodes_doc(args):
    from curve_formation.nodes.docs import nodes_markdown, settings_markdown
    print(settings_markdown() if args.settings else nodes_markdown())


def _output_folder(path, force=False):
    """Create the output folder now (not after a long run); OSError or FileExistsError, also
    for a folder that holds something already, unless force (its files are written over).
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise FileExistsError(f'{path}: exists and is not a folder; give a folder for --out')
    if not force and path.is_dir() and any(path.iterdir()):
        raise FileExistsError(f'{path}: output folder is not empty; give a new one, or '
                              '--force to write over what it holds')
    path.mkdir(parents=True, exist_ok=True)
    probe = path / '.curve_formation_write_test'
    probe.write_text('')
    probe.unlink()
    return path
