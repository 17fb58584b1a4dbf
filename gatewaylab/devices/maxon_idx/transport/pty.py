"""A pseudo-terminal that any program opens like a real serial port (e.g. pyserial, minicom).

The device keeps both ends open: the master end is read in the rig loop and fed to the protocol,
the slave end (``path``, /dev/pts/N) is what the host opens. Keeping our own handle on the slave
end means a host may close and reopen the port without the master end seeing EIO.
"""

from __future__ import annotations

import errno
import os
import termios
import tty

from gatewaylab.common.clock import Clock
from gatewaylab.devices.maxon_idx.transport.base import Channel, ChannelFactory, Reactor, ReplyWriter

__all__ = ["PtyPort"]


class PtyPort(ReplyWriter):
    """One virtual serial port carrying one IDX USB command channel.

    ``latency`` > 0 delays every reply by that many seconds on the clock (a realistic USB
    round trip is about 1 ms: one full-speed frame); 0 answers as fast as possible.
    """

    def __init__(self, reactor: Reactor, clock: Clock, make_channel: ChannelFactory,
                 latency: float = 0.0) -> None:
        super().__init__(clock, latency)
        self.reactor = reactor
        self.master_fd, self.slave_fd = os.openpty()
        tty.setraw(self.slave_fd, termios.TCSANOW)
        os.set_blocking(self.master_fd, False)
        self.path = os.ttyname(self.slave_fd)
        self.rx_bytes = 0
        self.read_errors = 0
        self.channel: Channel = make_channel(self.send)
        reactor.add_reader(self.master_fd, self._on_readable)

    def _on_readable(self) -> None:
        try:
            data = os.read(self.master_fd, 4096)
        except BlockingIOError:
            return
        except OSError as exc:
            if exc.errno != errno.EIO:      # EIO: no opener on the slave side, nothing to read
                self.read_errors += 1
            return
        if self._backlog:
            self._flush()
        if data:
            self.rx_bytes += len(data)
            self.channel.receive(data)

    def _write_now(self, data: bytearray) -> int:
        return os.write(self.master_fd, data)

    def close(self) -> None:
        """Stop serving the port and close both ends (idempotent)."""
        if self._closed:
            return
        self._closed = True
        self.reactor.remove_reader(self.master_fd)
        self.channel.close()
        os.close(self.master_fd)
        os.close(self.slave_fd)
