"""A parameters file `curve-formation params` writes applies to a node under the namespace
the user chooses.
"""

import math

from curve_formation.paths import resolve_config


def test_a_generated_file_applies_under_the_namespace_the_user_chooses(params_dir, ros):
    from curve_formation.nodes.formation_controller import FormationController
    context, add, _ = ros
    path = params_dir / 'params' / 'robot_3.formation_controller.yaml'
    node = add(FormationController(context=context, cli_args=[
        '--ros-args', '-r', '__ns:=/mona_3', '--params-file', str(path)]))
    assert node.get_fully_qualified_name() == '/mona_3/formation_controller'
    assert node.params.index == 3 and node.params.agent_count == 9
    # file -> parameters file (as rcl reads it, no limit as .inf) -> node: the same controller
    from curve_formation.core.config.agents import agent_configs
    from curve_formation.core.config.loading import load_experiment
    assert node.config == agent_configs(load_experiment(resolve_config('arena_demo')), 10.0)[2]
    assert node.config.limits.max_angular_rate == math.inf
