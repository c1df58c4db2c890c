"""The README's node reference is generated from the code, and the nodes match it."""

from pathlib import Path

import pytest
import rclpy
from rclpy.context import Context
from rclpy.parameter import Parameter

from curve_formation.nodes import docs
from curve_formation.runner import NODE_CLASSES


README = Path(__file__).resolve().parent.parent / 'README.md'


def test_readme_node_reference_is_the_generated_one():
    text = README.read_text()
    begin, end = '<!-- nodes:begin -->\n', '\n<!-- nodes:end -->'
    assert begin in text and end in text, 'README lacks the node reference markers'
    current = text.split(begin, 1)[1].split(end, 1)[0]
    assert current == docs.nodes_markdown(), (
        'README node reference is stale: regenerate with `curve-formation nodes-doc`')


@pytest.mark.ros
@pytest.mark.parametrize('name, module', [n for n in docs.NODES if n[0] != 'formation_recorder'])
def test_nodes_create_the_documented_topics(ros_domain, name, module):
    context = Context()
    rclpy.init(context=context)
    params = {'formation_controller': dict(index=2, agent_count=3, in_neighbours=[1],
                                           avoidance=True),
              'curve_server': dict(experiment='arena_demo'),   # re-assigns: robot poses
              'fake_robot': {},
              'fake_arena': dict(experiment='arena_demo'),
              'camera_tracker': dict(experiment='arena_demo'),
              'fake_camera': dict(experiment='arena_demo'),
              'robot_bridge': dict(link='udp:127.0.0.1:9')}[name]
    cls = getattr(module, NODE_CLASSES[module.__name__])
    node = cls(context=context, namespace='/robot_2',
               parameter_overrides=[Parameter(k, value=v) for k, v in params.items()])
    try:
        pubs = dict(node.get_publisher_names_and_types_by_node(node.get_name(), '/robot_2'))
        subs = dict(node.get_subscriber_names_and_types_by_node(node.get_name(), '/robot_2'))
        for direction, topic, msg_type, _, _ in module.TOPICS:
            resolved = (topic.replace('<j>', '1').replace('<i>', '1') if topic.startswith('/')
                        else f'/robot_2/{topic}')
            found = (pubs if direction == 'pub' else subs).get(resolved)
            package, name = msg_type.split('/')
            assert found == [f'{package}/msg/{name}'], (direction, resolved, found)
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)
