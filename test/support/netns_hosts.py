"""Several "hosts" on one machine, for tests and benchmarks of a graph split over hosts:
network namespaces joined by veth pairs on a bridge (needs root and iproute2).

Each host is a namespace with one interface, eth0 (10.231.<net>.<k>/24, multicast routed on
it), whose peer sits on a bridge in a namespace of its own. Nothing is created in or changed
on the machine's own network namespace: every link is made inside the namespaces. Traffic
between hosts is UDP over the bridge; taking a host's link down (`link`) cuts it.
"""

import os
import shutil
import signal
import subprocess


def available():
    """'' when namespaces can be made here, else why not."""
    if os.geteuid() != 0:
        return 'network namespaces need root'
    if shutil.which('ip') is None:
        return 'no `ip` command (iproute2)'
    name = f'cfprobe{os.getpid()}'
    made = subprocess.run(['ip', 'netns', 'add', name], capture_output=True, text=True)
    if made.returncode != 0:
        return f'cannot make a network namespace: {made.stderr.strip()}'
    subprocess.run(['ip', 'netns', 'delete', name], capture_output=True)
    return ''


def stop_groups(processes, timeout=30.0):
    """SIGINT the process group of every process still running (started with
    start_new_session, e.g. a `curve-formation run` on a host: it ends cleanly), then SIGKILL
    the group of any that has not ended within `timeout` (s). None entries are skipped.
    """
    processes = [p for p in processes if p is not None]
    for proc in processes:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGINT)
    for proc in processes:
        try:
            proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=5.0)


class Hosts:
    """A context manager: `count` hosts named <prefix>1.. on a bridge namespace <prefix>br.

    hosts.prefix(k) is the argv prefix that runs a command on host k (1-based);
    hosts.link(k, up) takes host k's link down or up (at the bridge).
    """

    def __init__(self, count, prefix=None, net=231):
        self.count = count
        self.prefix_name = prefix or f'cf{os.getpid() % 100000}h'
        self.net = net
        self.made = []

    def name(self, k):
        return f'{self.prefix_name}{k}'

    @property
    def bridge(self):
        return f'{self.prefix_name}br'

    def address(self, k):
        return f'10.{self.net}.0.{k}'

    def prefix(self, k):
        return ['ip', 'netns', 'exec', self.name(k)]

    def __enter__(self):
        try:
            self._ip('netns', 'add', self.bridge)
            self.made.append(self.bridge)
            self._in(self.bridge, 'ip', 'link', 'add', 'br0', 'type', 'bridge')
            self._in(self.bridge, 'ip', 'link', 'set', 'br0', 'up')
            for k in range(1, self.count + 1):
                host = self.name(k)
                self._ip('netns', 'add', host)
                self.made.append(host)
                # the pair is made inside the host's namespace, its peer moved to the bridge's
                self._in(host, 'ip', 'link', 'add', 'eth0', 'type', 'veth', 'peer', 'name',
                         f'port{k}', 'netns', self.bridge)
                self._in(host, 'ip', 'addr', 'add', f'{self.address(k)}/24', 'dev', 'eth0')
                self._in(host, 'ip', 'link', 'set', 'lo', 'up')
                self._in(host, 'ip', 'link', 'set', 'eth0', 'up')
                self._in(host, 'ip', 'route', 'add', '224.0.0.0/4', 'dev', 'eth0')
                self._in(self.bridge, 'ip', 'link', 'set', f'port{k}', 'master', 'br0')
                self._in(self.bridge, 'ip', 'link', 'set', f'port{k}', 'up')
        except BaseException:
            self.__exit__()
            raise
        return self

    def __exit__(self, *exc):
        for name in reversed(self.made):
            subprocess.run(['ip', 'netns', 'delete', name], capture_output=True)
        self.made = []

    def link(self, k, up):
        """Host k's link up or down, at its bridge port."""
        self._in(self.bridge, 'ip', 'link', 'set', f'port{k}', 'up' if up else 'down')

    def _ip(self, *args):
        subprocess.run(['ip', *args], check=True, capture_output=True, text=True)

    def _in(self, namespace, *argv):
        subprocess.run(['ip', 'netns', 'exec', namespace, *argv], check=True,
                       capture_output=True, text=True)
