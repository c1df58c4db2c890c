"""A recorded bag's topics carry the types and hashes ROS 2 Jazzy announces, and replay
loops until stopped.
"""

import threading

import rclpy

from cases import tiny_bag


def test_bag_topics_carry_the_types_and_hashes_ros_2_jazzy_announces(recorded, ros):
    """What `ros2 bag info/play` read: each topic's type, its RIHS01 type hash (as a Jazzy
    publisher of that type announces it in the graph), its QoS, and the message definitions.
    """
    import importlib
    import sqlite3

    import yaml
    folder, _ = recorded
    context, add, spin_until = ros
    node = add(rclpy.create_node('hash_probe', context=context))
    info = yaml.safe_load((folder / 'bag' / 'metadata.yaml').read_text())[
        'rosbag2_bagfile_information']
    assert info['version'] == 9 and info['storage_identifier'] == 'sqlite3'
    for entry in info['topics_with_message_count']:
        meta = entry['topic_metadata']
        package, _, name = meta['type'].split('/')
        msg_class = getattr(importlib.import_module(f'{package}.msg'), name)
        topic = '/hash_probe' + meta['name']
        node.create_publisher(msg_class, topic, 1)
        spin_until(lambda topic=topic: node.get_publishers_info_by_topic(topic))
        announced = node.get_publishers_info_by_topic(topic)[0].topic_type_hash
        assert meta['type_description_hash'] == str(announced), meta['name']
        assert meta['offered_qos_profiles'][0]['reliability'] in ('reliable', 'best_effort')
    with sqlite3.connect(folder / 'bag' / 'bag.db3') as db:
        defined = {row[0] for row in db.execute(
            "select topic_type from message_definitions where encoding = 'ros2msg' and "
            'length(encoded_message_definition) > 0')}
    assert defined >= {e['topic_metadata']['type'] for e in info['topics_with_message_count']}


def test_replay_loops_until_stopped(tmp_path, ros):
    from std_msgs.msg import Bool

    from curve_formation.bags.replay import replay
    context, add, spin_until = ros
    bag = tiny_bag(tmp_path / 'bag')
    node = add(rclpy.create_node('player', context=context))
    received = []
    node.create_subscription(Bool, '/replay_test', lambda m: received.append(m.data), 10)
    stop = threading.Event()

    def joins():
        # The bag is F T F T F; passes join as ... F F T ...: two joins = 3 passes played.
        return sum(a is False and b is False
                   for a, b in zip(received, received[1:], strict=False))

    player = threading.Thread(target=replay, args=(node, bag), kwargs=dict(
        loop=True, clock=False, wait_for_subscribers=5.0, stop=stop, log=lambda *_: None))
    player.start()
    try:
        spin_until(lambda: joins() >= 2, timeout=10.0)
    finally:
        stop.set()
        player.join(5.0)
    assert not player.is_alive()   # and the stop event ended the loop
