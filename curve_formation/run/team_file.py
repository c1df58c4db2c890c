"""The team a run drives once pre-flight has left robots out: the experiment file without
them, written beside the run's outputs (team.yaml).
"""

from pathlib import Path

import yaml

from curve_formation.core.config.errors import ConfigError
from curve_formation.core.config.loading import load_experiment, parse_experiment_text
from curve_formation.core.config.team import without_robots
from curve_formation.run.run_options import ROBOT_FAULTS


def write_team_file(experiment_path, missing, path):
    """The experiment file at experiment_path without the robots `missing` (1-based), written
    to `path` (core.config.team.without_robots; files it names made absolute) and checked
    (the graph left must still be rooted at the leader); returns path.
    """
    source = str(experiment_path)
    data = without_robots(parse_experiment_text(Path(experiment_path).read_bytes(), source),
                          missing, source)
    camera = data.get('camera') or {}
    for key in ('calibration_file', 'intrinsics_file'):
        if camera.get(key) and not Path(camera[key]).is_absolute():
            camera[key] = str((Path(experiment_path).parent / camera[key]).resolve())
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    try:
        load_experiment(path)
    except ConfigError as exc:
        kept = [i for i in range(1, int(data['agents']['count']) + len(missing) + 1)
                if i not in missing]
        said = str(exc).split(': ', 2)[-1]
        what = ('the graph left is not rooted at the leader, so the formation cannot run: '
                if exc.key == 'graph' else '')
        raise ConfigError(source, exc.key, f'without robots {sorted(missing)} {what}{said} '
                          f"(the team's agents 1..{len(kept)} are the file's robots "
                          f'{", ".join(map(str, kept))})') from None
    return path


def faults_of_team(faults, number):
    """The simulated robots' faults (RunOptions.faults) of a team renumbered by `number`
    ({robot of the file: robot of the team}): a left-out robot's dropped.
    """
    if not faults:
        return faults
    out = dict(faults)
    for key in ROBOT_FAULTS:
        if key in out:
            out[key] = [number[i] for i in out[key] if i in number]
    if 'link_down' in out:
        robot, *when = out['link_down']
        if robot != 0 and int(robot) not in number:
            del out['link_down']
        elif robot != 0:
            out['link_down'] = [number[int(robot)], *when]
    return out
