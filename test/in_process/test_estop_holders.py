"""The e-stop's holders in the test's process: any publisher stops every holder, a release
waits for the holders heard, the command holds the stop until Ctrl-C.
"""

import os
import signal
import subprocess
import sys
import time

import pytest
import rclpy
from std_msgs.msg import Bool

from conftest import CONFIG_DIR, no_history_qos
from curve_formation.nodes import messages, qos, topics


def test_estop_command_holds_the_stop_sending_it_again_until_ctrl_c(ros):
    """`curve-formation estop on --hold`: a controller that never got the latched message
    (a volatile subscription here: no history) still gets the stop, within a second; a late
    latched one gets it at once; Ctrl-C ends the command cleanly, with status 1 since no
    controller confirmed the stop (this probe is none).
    """
    context, add, spin_until = ros
    node = add(rclpy.create_node('probe', context=context))
    volatile = []
    node.create_subscription(Bool, topics.ESTOP, lambda m: volatile.append(m.data),
                             no_history_qos())
    proc = subprocess.Popen([sys.executable, '-m', 'curve_formation.cli', 'estop', 'on',
                             '--hold', '--wait', '0'], env=dict(os.environ),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        spin_until(lambda: len(volatile) >= 2, timeout=20.0)
        assert all(volatile)
        latched = []
        node.create_subscription(Bool, topics.ESTOP, lambda m: latched.append(m.data),
                                 qos.LATCHED)
        spin_until(lambda: latched, timeout=5.0)
        assert latched[0] is True
    finally:
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=20)
    assert proc.returncode == 1 and 'sending it every 1 s; Ctrl-C to quit' in out, (out, err)
    assert 'no formation controller answered' in err


def _holders(context, add, count, first=0):
    from rclpy.node import Node

    from curve_formation.nodes.estop import EstopHolder
    out = []
    for i in range(first, first + count):
        node = add(Node('formation_controller', namespace=f'/robot_{i + 1}', context=context))
        out.append(EstopHolder(node, f'robot_{i + 1}', 9))
    return out


@pytest.mark.parametrize('reliability', ['reliable', 'best_effort'])
def test_any_publisher_stops_every_holder_even_when_it_reached_only_one(ros, reliability):
    """A publisher as `ros2 topic pub` makes one (volatile; reliable by default, or best
    effort) stops every node holding the e-stop although it sent a single message once it had
    found one of them: the node that got it passes it on. Only a release command releases, and
    it must reach each node itself.
    """
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    context, add, spin_until = ros
    holders = _holders(context, add, 3)
    spin_until(lambda: all(len(h.node.get_subscriptions_info_by_topic(topics.ESTOP_STATE)) >= 3
                           for h in holders), timeout=10.0)
    profile = QoSProfile(depth=10, durability=DurabilityPolicy.VOLATILE,
                         reliability=getattr(ReliabilityPolicy, reliability.upper()))
    pedal = add(rclpy.create_node('foot_pedal', context=context))
    pub = pedal.create_publisher(Bool, topics.ESTOP, profile)
    spin_until(lambda: pub.get_subscription_count() >= 1, timeout=10.0)
    pub.publish(Bool(data=True))
    spin_until(lambda: all(h.engaged for h in holders), timeout=5.0)
    assert all(h.latch.by == '/foot_pedal' for h in holders), [h.latch.by for h in holders]
    readers = 6 if reliability == 'reliable' else 3   # reliable: two readers in each node
    spin_until(lambda: pub.get_subscription_count() >= readers, timeout=10.0)
    pub.publish(Bool(data=False))
    spin_until(lambda: not any(h.engaged for h in holders), timeout=5.0)


def test_a_node_that_starts_while_stopped_stays_stopped_without_a_command(ros):
    """No sender left: the stop is held by the nodes that got it and taken up by a new one."""
    context, add, spin_until = ros
    holders = _holders(context, add, 2)
    sender = add(rclpy.create_node('formation_estop', context=context))
    pub = sender.create_publisher(Bool, topics.ESTOP, qos.LATCHED)
    spin_until(lambda: pub.get_subscription_count() >= 4, timeout=10.0)
    pub.publish(Bool(data=True))
    spin_until(lambda: all(h.engaged for h in holders), timeout=5.0)
    sender.destroy_publisher(pub)
    late = _holders(context, add, 1, first=5)[0]
    spin_until(lambda: late.engaged, timeout=5.0)
    assert late.latch.by == '/formation_estop'


def test_a_node_that_has_discovered_another_holder_waits_for_its_state_past_the_silence(ros):
    """Silence means 'not stopped' only to a node alone on the domain. A controller restarted
    under load while the e-stop was held found its peers only after nodes.estop.HEAR_WAIT s
    and drove once: a holder discovered but not yet heard keeps the node stopped past
    HEAR_WAIT, and its state, once it comes, decides.
    """
    from rclpy.node import Node

    from curve_formation.nodes import messages
    from curve_formation.nodes.estop import EstopHolder, HEAR_WAIT
    context, add, spin_until = ros
    peer = add(rclpy.create_node('slow_peer', context=context))
    state = topics.publisher(peer, topics.ESTOP_STATE)   # publishes when told, below
    told = []
    node = add(Node('formation_controller', namespace='/robot_1', context=context))
    holder = EstopHolder(node, 'robot_1', 9, on_change=told.append)
    spin_until(lambda: node.count_publishers(topics.ESTOP_STATE) >= 2, timeout=10.0)
    waited = time.monotonic() + 2.5 * HEAR_WAIT
    spin_until(lambda: time.monotonic() > waited, timeout=3 * HEAR_WAIT)
    assert not holder.heard and told == []
    state.publish(messages.estop_state_to_msg('/slow_peer', 'slow_peer', '', True,
                                              '/formation_estop', time.time(), 9))
    spin_until(lambda: holder.heard, timeout=5.0)
    assert told == [True] and holder.engaged


def test_a_node_alone_takes_the_silence_as_not_stopped(ros):
    """With no other holder discovered, HEAR_WAIT s of silence release a node that waits."""
    from rclpy.node import Node

    from curve_formation.nodes.estop import EstopHolder, HEAR_WAIT
    context, add, spin_until = ros
    told = []
    node = add(Node('formation_controller', namespace='/robot_1', context=context))
    clock = node.get_clock()   # the clock the holder's timer runs on (monotonic was 4 ms short)
    started = clock.now()
    EstopHolder(node, 'robot_1', 9, on_change=told.append)
    spin_until(lambda: told, timeout=3 * HEAR_WAIT)
    assert told == [False] and (clock.now() - started).nanoseconds * 1e-9 >= HEAR_WAIT


def test_fake_robots_stand_still_while_stopped_whatever_cmd_vel_says(ros):
    """A controller that crashed while driving (or any other publisher) cannot move a fake
    robot, nor a robot of the fake arena, while the e-stop is engaged.
    """
    from geometry_msgs.msg import Twist
    from rclpy.parameter import Parameter

    from curve_formation.nodes.fake_arena import FakeArena
    from curve_formation.nodes.fake_robot import FakeRobot
    context, add, spin_until = ros
    robot = add(FakeRobot(context=context, namespace='/robot_1'))
    arena = add(FakeArena(context=context, parameter_overrides=[
        Parameter('experiment', value=str(CONFIG_DIR / 'arena_demo.yaml'))]))
    driver = add(rclpy.create_node('crashed_controller', context=context))
    cmd = driver.create_publisher(Twist, topics.robot_topic(1, topics.CMD_VEL), qos.COMMAND)
    estop = driver.create_publisher(Bool, topics.ESTOP, no_history_qos())
    spin_until(lambda: cmd.get_subscription_count() >= 2 and estop.get_subscription_count())
    estop.publish(Bool(data=True))
    spin_until(lambda: robot.estop.engaged and arena.estop.engaged, timeout=5.0)
    before = robot.pose, tuple(arena.world.poses()[0])
    end = time.monotonic() + 1.0
    moving = Twist()
    moving.linear.x, moving.angular.z = 0.02, 0.3
    while time.monotonic() < end:
        cmd.publish(moving)
        pause = time.monotonic() + 0.05
        spin_until(lambda pause=pause: time.monotonic() > pause)
    assert (robot.pose, tuple(arena.world.poses()[0])) == before


def test_the_holders_of_one_process_share_one_subscription_to_the_states_and_hear_alike(ros):
    """A group's nodes (node_group) read the holders' states through one subscription: a
    stop announced by a holder elsewhere is passed on to each of them, and each hears every
    holder.
    """

    from rclpy.node import Node

    from curve_formation.nodes.estop import EstopHolder
    from curve_formation.nodes.shared_readers import readers_shared
    context, add, spin_until = ros
    with readers_shared():
        grouped = [EstopHolder(add(Node('formation_controller', namespace=f'/robot_{i}',
                                        context=context)), f'robot_{i}', 3)
                   for i in (1, 2)]
    elsewhere = EstopHolder(add(Node('fake_arena', context=context)), robots=3)
    probe = add(Node('probe', context=context))
    spin_until(lambda: probe.count_publishers(topics.ESTOP_STATE) == 3)
    assert probe.count_subscribers(topics.ESTOP_STATE) == 2   # the group's and the arena's
    assert elsewhere.latch.command(True, 10.0, '/pedal', 10.0)
    elsewhere.announce()
    spin_until(lambda: all(holder.engaged for holder in grouped))
    spin_until(lambda: [holder.holders() for holder in (*grouped, elsewhere)] == [3, 3, 3])


def test_the_command_discovers_the_holders_that_are_not_controllers(ros):
    from rclpy.node import Node

    from curve_formation.nodes.estop import EstopHolder
    from curve_formation.run.estop_command import other_holders
    context, add, spin_until = ros
    for name, namespace in (('fake_arena', '/'), ('fake_robot', '/robot_2'),
                            ('formation_controller', '/robot_1')):
        EstopHolder(add(Node(name, namespace=namespace, context=context)))
    probe = add(Node('formation_estop', context=context))
    spin_until(lambda: len(probe.get_publishers_info_by_topic(topics.ESTOP_STATE)) == 3)
    assert other_holders(probe, topics.ESTOP_STATE) == {'/fake_arena', '/robot_2/fake_robot'}
    # and each holder, having heard the other two, announces that it hears three
    heard = {}
    topics.subscription(probe, topics.ESTOP_STATE, lambda msg: heard.update(
        {msg.name: messages.estop_state_from_msg(msg).holders}))
    spin_until(lambda: len(heard) == 3 and set(heard.values()) == {3}, timeout=5.0)
