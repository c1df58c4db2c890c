"""Each node process creates the topics the node reference (docs/nodes.md) documents."""


import pytest
import rclpy
from rclpy.context import Context
from rclpy.parameter import Parameter

from curve_formation.nodes import docs, qos, topics
from curve_formation.run.launches import node_class


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
