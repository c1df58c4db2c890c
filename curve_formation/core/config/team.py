"""An experiment file's team without some of its robots: what a run drives when pre-flight
leaves robots out (`run --allow-missing`). The robots left keep their order and are numbered
1.. again; every per-agent key follows them.
"""

import copy
from typing import Any

from curve_formation.core.config.errors import ConfigError


def without_robots(data: dict[str, Any], missing: set[int], source: str) -> dict[str, Any]:
    """The experiment's raw YAML data (as read) without the robots `missing` (1-based): the
    agents' count and explicit start poses, the graph's edges (those of a robot left out
    dropped, the rest renumbered), per-agent disturbances and their variations' agents, the
    camera's robot_ids and the fleet. ConfigError if the leader would be left out or no robot
    would remain; whether the graph left is still rooted is the loader's check.
    """
    n = int(data['agents']['count'])
    missing = {int(i) for i in missing}
    unknown = sorted(i for i in missing if not 1 <= i <= n)
    if unknown:
        raise ConfigError(source, 'agents.count', f'robots {unknown} are not in 1..{n}')
    leader = int(data.get('graph', {}).get('leader', 1))
    if leader in missing:
        raise ConfigError(source, 'graph.leader', f'robot {leader} is the leader: the '
                          'formation cannot run without it')
    kept = [i for i in range(1, n + 1) if i not in missing]
    number = {old: new for new, old in enumerate(kept, 1)}
    out = copy.deepcopy(data)
    out['agents']['count'] = len(kept)
    initial = out['agents'].get('initial', {})
    if isinstance(initial.get('poses'), list):
        initial['poses'] = [initial['poses'][i - 1] for i in kept]
    graph = out.get('graph', {})
    graph['edges'] = [{**edge, 'from': number[int(edge['from'])], 'to': number[int(edge['to'])]}
                      for edge in graph.get('edges', [])
                      if int(edge['from']) in number and int(edge['to']) in number]
    disturbance = out.get('disturbance') or {}
    if isinstance(disturbance.get('per_agent'), list):
        disturbance['per_agent'] = [disturbance['per_agent'][i - 1] for i in kept]
    for variation in disturbance.get('varies') or []:
        if variation.get('agents') is not None:
            variation['agents'] = [number[int(i)] for i in variation['agents']
                                   if int(i) in number]
    camera = out.get('camera') or {}
    if camera.get('robot_ids'):
        camera['robot_ids'] = [camera['robot_ids'][i - 1] for i in kept]
    robots = out.get('robots') or {}
    if robots.get('fleet'):
        robots['fleet'] = [robots['fleet'][i - 1] for i in kept]
    return out
