"""The topics a group's nodes share (nodes/shared_readers.py): a robot's state handed over to
its neighbours in the same process, published on DDS only for readers elsewhere.
"""

from rclpy.node import Node

from curve_formation.core.controller.inputs import State
from curve_formation.interface import robot_topic
from curve_formation.nodes import messages, topics
from curve_formation.nodes.shared_readers import publish_robot, readers_shared, subscribe_robot


def test_a_groups_states_are_handed_over_and_published_only_for_readers_elsewhere(ros):
    """Robot 2 reads robot 1 in the same process: no DDS subscription, the state arrives
    as it is published (a reader that fails is rejected, the next still gets it); nothing
    goes on DDS until a reader elsewhere appears, which then gets it over DDS; a neighbour
    outside the group (robot 3) is read from DDS.
    """
    context, add, spin_until = ros
    probe = add(Node('probe', context=context))
    with readers_shared(['/robot_1', '/robot_2']):
        one = add(Node('formation_controller', namespace='/robot_1', context=context))
        two = add(Node('formation_controller', namespace='/robot_2', context=context))
        handed = []

        def failing(msg):
            raise ValueError('a reader that cannot take it')

        subscribe_robot(two, topics.STATE, 1, failing)
        subscribe_robot(two, topics.STATE, 1, handed.append)
        subscribe_robot(two, topics.STATE, 3, lambda msg: None)
        publisher = topics.publisher(one, topics.STATE)
        msg = messages.state_to_msg(State((0.1, -0.2), 4, 12.5, 0.3))
        spin_until(lambda: probe.count_subscribers(robot_topic(3, topics.STATE)) == 1)
        assert probe.count_subscribers(robot_topic(1, topics.STATE)) == 0
        publish_robot(publisher, msg)
        assert handed == [msg]
        assert publisher.get_subscription_count() == 0   # so nothing was published
        heard = []
        topics.subscription(probe, topics.STATE, heard.append, robot=1)
        spin_until(lambda: publisher.get_subscription_count() == 1)
        publish_robot(publisher, msg)
        spin_until(lambda: heard)
        assert messages.state_from_msg(heard[0]) == (0.1, -0.2, 4, 12.5, 0.3)
        assert len(handed) == 2
