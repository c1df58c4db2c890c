"""The node reference (docs/nodes.md) is generated from the code, and the nodes match it."""

from pathlib import Path

import pytest
import rclpy
from rclpy.context import Context
from rclpy.parameter import Parameter

from curve_formation.nodes import docs, qos, topics
from curve_formation.run.launches import node_class


NODE_REFERENCE = Path(__file__).resolve().parent.parent / 'docs' / 'nodes.md'


GENERATED = [   # (page, marker, the table as the code makes it, the command that prints it)
    ('nodes.md', 'nodes', docs.nodes_markdown, 'curve-formation nodes-doc'),
    ('experiments.md', 'settings', docs.settings_markdown,
     'curve-formation nodes-doc --settings'),
]


@pytest.mark.parametrize('page, marker, generated, command', GENERATED,
                         ids=[g[0] for g in GENERATED])
def test_a_reference_table_is_the_generated_one(page, marker, generated, command):
    text = (NODE_REFERENCE.parent / page).read_text()
    begin, end = f'<!-- {marker}:begin -->\n', f'\n<!-- {marker}:end -->'
    assert begin in text and end in text, f'docs/{page} lacks the {marker} markers'
    current = text.split(begin, 1)[1].split(end, 1)[0]
    assert current == generated(), f'docs/{page} is stale: regenerate with `{command}`'


def test_a_run_records_every_robots_topics_once_with_their_registered_types():
    recorded = topics.recorded(3)
    names = [t.name for t in recorded]
    assert len(names) == len(set(names)) == 9 + 5 * 3   # markers, robot_poses, fleet, preflight
    assert '/robot_3/cmd_vel' in names and '/formation/curve' in names
    assert topics.REGISTRY['cmd_vel'].type_name == 'geometry_msgs/msg/Twist'
    with_images = [t.name for t in topics.recorded(3, images=True)]
    assert set(with_images) - set(names) == {topics.CAMERA_IMAGE, topics.CAMERA_POSES}


@pytest.mark.ros
@pytest.mark.parametrize('name, module', [n for n in docs.NODES if n[0] != 'formation_recorder'])
def test_nodes_create_the_documented_topics(ros_domain, name, module):
    context = Context()
    rclpy.init(context=context)
    params = {'formation_controller': dict(index=2, agent_count=3, in_neighbours=[1],
                                           avoidance=True),
              # re-assigns: robot poses; waits for each robot's pose
              'curve_server': dict(experiment='arena_demo', wait_for_poses=True),
              'fake_robot': {},
              'fake_arena': dict(experiment='arena_demo'),
              'camera_tracker': dict(experiment='arena_demo'),
              'fake_camera': dict(experiment='arena_demo'),
              'robot_bridge': dict(link='udp:127.0.0.1:9')}[name]
    cls = node_class(module.__name__)
    node = cls(context=context, namespace='/robot_2',
               parameter_overrides=[Parameter(k, value=v) for k, v in params.items()])
    try:
        pubs = dict(node.get_publisher_names_and_types_by_node(node.get_name(), '/robot_2'))
        subs = dict(node.get_subscriber_names_and_types_by_node(node.get_name(), '/robot_2'))
        for use in module.TOPICS:
            shown = use.shown_name
            resolved = (shown.replace('<j>', '1').replace('<i>', '1') if shown.startswith('/')
                        else f'/robot_2/{shown}')
            found = (pubs if use.direction == 'pub' else subs).get(resolved)
            registered = topics.REGISTRY[use.name]
            assert found == [registered.type_name], (use.direction, resolved, found)
            infos = (node.get_publishers_info_by_topic if use.direction == 'pub'
                     else node.get_subscriptions_info_by_topic)(resolved)
            mine = [info.qos_profile for info in infos if info.node_name == node.get_name()]
            wanted = [registered.profile if use.direction == 'pub'
                      else registered.reader_profile]
            if use.direction == 'sub' and use.name == topics.ESTOP:   # nodes/estop.py
                wanted.append(qos.ESTOP_RELIABLE)
            assert sorted((q.reliability, q.durability) for q in mine) == sorted(
                (q.reliability, q.durability) for q in wanted), resolved
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)


def test_the_readme_example_experiment_is_valid_and_settles(tmp_path):
    """The minimal experiment the README shows passes check and settles in the simulator."""
    from curve_formation.core.config.loading import load_experiment
    from curve_formation.core.record.metrics import result_metrics
    from curve_formation.core.sim.batch import simulate
    text = (NODE_REFERENCE.parent.parent / 'README.md').read_text()
    begin = text.index('```yaml\nname: my_loop')
    path = tmp_path / 'my_loop.yaml'
    path.write_text(text[begin + len('```yaml\n'):text.index('```', begin + 7)])
    metrics = result_metrics(simulate(load_experiment(path)))
    assert metrics['all_settled'], metrics['phases']
