"""Byte links to robots: UDP datagrams, a serial port (pyserial), and the robot's side of both
(a UDP endpoint, a pseudo-terminal) for the emulated robots. Lines end with a newline.

Every link is non-blocking: send() writes or raises LinkError, lines() returns the complete
lines received so far. A serial port that fails (unplugged, a radio reset) is closed and
reopened, at most once a second, when the next send finds it closed.
"""

import os
from pathlib import Path
import socket
import time

import serial

from curve_formation.core.config.fleet import DEFAULT_BAUD, parse_link


MAX_LINE = 4096           # bytes a line may hold before it is dropped as garbage
REOPEN_PERIOD = 1.0       # s between two attempts to reopen a serial port


class LinkError(OSError):
    """A link that cannot carry the bytes now; the message says why."""


class _Lines:
    """Splits a byte stream into lines (terminator kept), dropping over-long ones."""

    def __init__(self):
        self.buffer = b''
        self.dropped = 0

    def feed(self, data):
        self.buffer += data
        *complete, self.buffer = self.buffer.split(b'\n')
        if len(self.buffer) > MAX_LINE:
            self.buffer, self.dropped = b'', self.dropped + 1
        out = []
        for line in complete:
            if len(line) > MAX_LINE:
                self.dropped += 1
            else:
                out.append(line + b'\n')
        return out


def _datagram_lines(sock, lines):
    """(complete lines, last sender) of every datagram waiting on non-blocking `sock`, fed to
    `lines` (a _Lines); a datagram ends its line even without a terminator.
    """
    out: list[bytes] = []
    sender = None
    while True:
        try:
            data, sender = sock.recvfrom(65536)
        except OSError:   # none left (BlockingIOError), or e.g. ICMP port unreachable
            return out, sender
        out += lines.feed(data if data.endswith(b'\n') else data + b'\n')


def parse_address(text):
    """('udp', (host, port)), ('serial', device) or ('pty', path) of 'udp:HOST:PORT',
    'serial:DEVICE[@BAUD]' or 'pty:PATH' (core.config.fleet.parse_link); ValueError if it is
    none of them.
    """
    address = parse_link(text)
    if address.kind == 'udp':
        return 'udp', (address.host, address.port)
    return address.kind, address.device


class UdpLink:
    """Datagrams to a robot at (host, port); its replies come back to the same socket."""

    def __init__(self, peer):
        self.peer = peer
        self.socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.socket.setblocking(False)
        self._lines = _Lines()

    def send(self, data):
        try:
            self.socket.sendto(data, self.peer)
        except OSError as exc:
            raise LinkError(f'udp {self.peer[0]}:{self.peer[1]}: {exc.strerror or exc}') from None

    def lines(self):
        return _datagram_lines(self.socket, self._lines)[0]

    @property
    def dropped(self):
        return self._lines.dropped

    def close(self):
        self.socket.close()


class SerialLink:
    """A serial port (pyserial) at `baud`, reopened when it comes back after a failure."""

    def __init__(self, device, baud=115200):
        self.device, self.baud = device, baud
        self.port = None
        self.last_attempt = -float('inf')
        self._lines = _Lines()
        self.opened = 0     # times the port was opened
        self.error = ''

    def _open(self):
        now = time.monotonic()
        if now - self.last_attempt < REOPEN_PERIOD:   # the same error until the next attempt
            raise LinkError(self.error)
        self.last_attempt = now
        try:
            self.port = serial.Serial(self.device, self.baud, timeout=0, write_timeout=0.05)
        except (OSError, serial.SerialException) as exc:
            self.error = f'serial {self.device}: {exc}'
            raise LinkError(self.error) from None
        self.opened += 1

    def send(self, data):
        if self.port is None:
            self._open()
        port = self.port
        assert port is not None   # _open opened it or raised LinkError
        try:
            port.write(data)
        except (OSError, serial.SerialException) as exc:
            self.close()
            self.error = f'serial {self.device}: {exc}'
            raise LinkError(self.error) from None

    def lines(self):
        if self.port is None:
            return []
        try:
            waiting = self.port.in_waiting
            return self._lines.feed(self.port.read(waiting)) if waiting else []
        except (OSError, serial.SerialException):
            self.close()
            return []

    @property
    def dropped(self):
        return self._lines.dropped

    def close(self):
        if self.port is not None:
            try:
                self.port.close()
            except OSError:
                pass
        self.port = None


def robot_link(address, baud=DEFAULT_BAUD):
    """The bridge's link to a robot at 'udp:HOST:PORT' or 'serial:DEVICE' (at `baud`, or at
    the address's own '@BAUD').
    """
    parsed = parse_link(address)
    baud = parsed.baud if '@' in address else baud
    kind, where = parse_address(address)
    if kind == 'udp':
        return UdpLink(where)
    if kind == 'serial':
        return SerialLink(where, baud)
    raise ValueError(f'a robot is reached over udp: or serial:, got {address!r}')


class UdpEndpoint:
    """The robot's side of a UDP link: bound to (host, port), it answers the last sender."""

    def __init__(self, where):
        self.socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.socket.bind(where)
        except OSError as exc:
            self.socket.close()
            raise OSError(exc.errno, f'udp {where[0]}:{where[1]}: {exc.strerror}') from None
        self.socket.setblocking(False)
        self.sender = None
        self._lines = _Lines()

    def lines(self):
        out, sender = _datagram_lines(self.socket, self._lines)
        self.sender = sender or self.sender
        return out

    def send(self, data):
        if self.sender is not None:
            try:
                self.socket.sendto(data, self.sender)
            except OSError:
                pass

    def close(self):
        self.socket.close()


class PtyEndpoint:
    """The robot's side of a serial line: a pseudo-terminal whose other side, in raw mode, is
    reachable at `path` (a symbolic link made here), as a USB serial adapter would be.
    """

    def __init__(self, path):
        import tty
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        os.set_blocking(self.master, False)
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if self.path.is_symlink() or self.path.exists():
            self.path.unlink()
        self.path.symlink_to(os.ttyname(self.slave))
        self._lines = _Lines()

    def lines(self):
        out: list[bytes] = []
        while True:
            try:
                data = os.read(self.master, 65536)
            except (BlockingIOError, InterruptedError):
                return out
            except OSError:
                return out
            if not data:
                return out
            out += self._lines.feed(data)

    def send(self, data):
        try:
            os.write(self.master, data)
        except OSError:
            pass

    def close(self):
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass
        try:
            self.path.unlink()
        except OSError:
            pass


def robot_endpoint(address):
    """The emulated robot's side of a link: 'udp:HOST:PORT' (bound) or 'pty:PATH'."""
    kind, where = parse_address(address)
    if kind == 'udp':
        return UdpEndpoint(where)
    if kind == 'pty':
        return PtyEndpoint(where)
    raise ValueError(f'an emulated robot listens on udp: or pty:, got {address!r}')
