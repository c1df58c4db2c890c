"""`curve-formation estop on|off`: engage or release every robot's e-stop and say truly whom
it reached.

The command sends the e-stop on /formation/estop again every RESEND_PERIOD until every
expected robot's controller has confirmed it in its own state on /formation/estop_state
(nodes/estop.py), and every other holder (robot bridges, fake robots or arena, the curve
server) discovered on that topic (for DISCOVERY_QUIET s at least) or heard there says the
same, and it has heard as many holders as the holders say they hear (a curve server that
discovery had not shown the command within its DISCOVERY_QUIET kept a released formation's
e-stop: a release comes only from a command), or `wait` seconds have passed:
a release that reached every controller, but not the fake arena the command had not heard
yet, left the arena's robots stopped once the command was gone. The robots expected are
`expect` (from --expect or --experiment), else as many as the controllers and the curve server
on the domain say the formation has. It reports how many confirmed and how fast, names the
ones that did not, and returns 0 only when all did. Each node holds the state it was given
(latched there), so the command need not stay up; `hold` keeps it sending every second until
Ctrl-C all the same.
"""

from dataclasses import dataclass, field
import os
import sys
import time

from curve_formation.interface import robot_name
from curve_formation.paths import discovery_text


RESEND_PERIOD = 0.1   # s between two sends while robots have not confirmed
HOLD_PERIOD = 1.0     # s between two sends with --hold, once confirmed
LOOK_PERIOD = 0.2     # s between two looks at which nodes publish e-stop states
# s the command keeps discovering after its first send, and after the last holder it
# discovered, before it believes it knows them all: a holder not discovered yet cannot be
# waited for (a release reached all nine controllers and the fake arena, not yet the curve
# server, and the command had ended; a new participant was seen to find its peers only after
# 2 s under load)
DISCOVERY_QUIET = 2.0
CONTROLLER = 'formation_controller'


@dataclass
class Tally:
    """The e-stop states heard, and when each robot's controller first confirmed the wanted
    one (s since the first send).
    """

    engage: bool
    expect: int | None = None
    reports: dict = field(default_factory=dict)      # holder -> messages.EstopReport
    confirmed: dict = field(default_factory=dict)    # robot -> s since the first send
    discovered: set = field(default_factory=set)     # other holders publishing their state

    def add(self, report, elapsed):
        self.reports[report.holder] = report
        if report.role == CONTROLLER and report.robot:
            if report.engaged == self.engage:
                self.confirmed.setdefault(report.robot, elapsed)
            else:
                self.confirmed.pop(report.robot, None)

    def expected(self):
        """The robots expected: robot_1 .. robot_n, n from `expect` or the reports (None
        before any report tells it).
        """
        n = self.expect or max((r.robots for r in self.reports.values()), default=0)
        return [robot_name(i) for i in range(1, n + 1)] if n else None

    def missing(self):
        expected = self.expected()
        return None if expected is None else [r for r in expected if r not in self.confirmed]

    def others_missing(self):
        """The other holders (robot bridges, fake robots or arena, the curve server) heard
        with another state than the wanted one, or discovered and not heard yet: a release
        that reached every controller but not the arena's robots leaves them stopped.
        """
        wrong = {holder for holder, report in self.reports.items()
                 if report.role != CONTROLLER and report.engaged != self.engage}
        return sorted(wrong | (self.discovered - set(self.reports)))

    def unheard(self):
        """How many holders the others hear announce that this command has not heard: ones
        discovery has not shown it yet, which it cannot name.
        """
        known = max((r.holders for r in self.reports.values()), default=0)
        return max(0, known - len(self.reports))

    def done(self, quiet=True):
        """Every expected robot and every other holder confirmed, every holder the others
        hear heard; quiet: discovery has had its time (DISCOVERY_QUIET) to show the holders
        not heard yet.
        """
        return (quiet and self.missing() == [] and not self.others_missing()
                and not self.unheard())


def send_estop(engage, expect=None, wait=10.0, hold=False, log=None):
    """Send the e-stop (engage True) or its release and wait for confirmations; the exit
    status: 0 every expected robot confirmed, 1 otherwise. log(text, ok): where the outcome
    goes (default: stdout when ok, else stderr).
    """
    log = log or _print
    import rclpy
    from rclpy.executors import ExternalShutdownException
    from std_msgs.msg import Bool

    from curve_formation.nodes import messages, topics

    start = time.monotonic()
    tally = Tally(engage, expect)
    rclpy.init()
    node = rclpy.create_node('formation_estop', start_parameter_services=False)
    word = 'on' if engage else 'off'
    status = 1
    try:
        def heard(msg):
            try:
                tally.add(messages.estop_state_from_msg(msg), time.monotonic() - first_send)
            except messages.MessageError:
                pass
        pub = topics.publisher(node, topics.ESTOP)
        topics.subscription(node, topics.ESTOP_STATE, heard)
        message = Bool(data=engage)
        first_send = time.monotonic()
        pub.publish(message)
        last_send = last_look = last_new = first_send
        tally.discovered = other_holders(node, topics.ESTOP_STATE)

        def quiet():
            return time.monotonic() - last_new >= DISCOVERY_QUIET
        while not tally.done(quiet()) and time.monotonic() - start < wait:
            rclpy.spin_once(node, timeout_sec=0.01)
            if time.monotonic() - last_send >= RESEND_PERIOD:
                pub.publish(message)
                last_send = time.monotonic()
            if time.monotonic() - last_look >= LOOK_PERIOD:
                found = other_holders(node, topics.ESTOP_STATE)
                if found - tally.discovered:
                    last_new = time.monotonic()
                tally.discovered = found
                last_look = time.monotonic()
        status = _report(tally, word, wait, log)
        if hold:
            log(f'e-stop {word}: sending it every {HOLD_PERIOD:g} s; Ctrl-C to quit', True)
            while True:
                rclpy.spin_once(node, timeout_sec=HOLD_PERIOD)
                pub.publish(message)
        else:
            pub.wait_for_all_acked(rclpy.duration.Duration(seconds=0.5))
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return status


def other_holders(node, topic):
    """The fully qualified names of the nodes other than controllers that publish `topic`
    (their e-stop state), as discovery knows them now: a publisher whose node discovery has
    not named (rmw's _NODE_NAME_UNKNOWN_; one stayed so for the whole 5 s of a test's
    command) is left out, as no state can be told to be its.
    """
    return {f"{info.node_namespace.rstrip('/')}/{info.node_name}"
            for info in node.get_publishers_info_by_topic(topic)
            if info.node_name != CONTROLLER and not info.node_name.startswith('_NODE_')}


def _report(tally, word, wait, log):
    """Print what the e-stop reached; the exit status."""
    done = 'stopped' if tally.engage else 'released'
    expected = tally.expected()
    holding = sum(1 for r in tally.reports.values() if r.role != CONTROLLER
                  and r.engaged == tally.engage)
    held = f'; {holding} other nodes hold it too' if holding else ''
    if expected is None:
        domain = os.environ.get('ROS_DOMAIN_ID', '0 (unset)')
        log(f'error: e-stop {word}: no formation controller answered within {wait:g} s on '
            f'ROS_DOMAIN_ID={domain}, discovery range {discovery_text()}: is the formation '
            'running on this domain and discovery range?', False)
        return 1
    missing = tally.missing()
    confirmed = [r for r in expected if r not in missing]
    slowest = max((tally.confirmed[r] for r in confirmed), default=0.0)
    silent = missing + tally.others_missing()   # the names of those that did not confirm
    unheard = tally.unheard()   # and how many more the others hear, not named by discovery
    if not silent and not unheard:
        log(f'e-stop {word}: {len(confirmed)} of {len(expected)} robots {done} within '
            f'{slowest:.2f} s{held}', True)
        return 0
    unnamed = ([f'{unheard} holder(s) the others hear and discovery did not show']
               if unheard else [])
    log(f'error: e-stop {word}: {len(confirmed)} of {len(expected)} robots confirmed '
        f'{done} within {wait:g} s; no confirmation from {", ".join(silent + unnamed)}{held}',
        False)
    return 1


def _print(text, ok):
    print(text, file=sys.stdout if ok else sys.stderr, flush=True)
