"""A recorded bag's topics carry the types and hashes ROS 2 Jazzy announces. Here, beside
test_replay, which shares its recorded run (the session's `recorded`): in test/in_process
the run was recorded a second time, 17 s of the default test run.
"""

import rclpy


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
