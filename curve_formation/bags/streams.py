"""Names of a topic's writer streams, shared by the nodes (what each one published) and the bag
(what was recorded of each): plain strings, so a node need not import the bag library.
"""


def stream_key(topic, writer=None):
    """Names one writer's stream of a topic: the topic, or with several writers on it (as on
    /diagnostics), the topic and that writer's name.
    """
    return topic if writer is None else f'{topic} {writer}'


def stream_topic(key):
    """The topic of a stream_key."""
    return key.split(' ', 1)[0]
