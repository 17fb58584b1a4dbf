"""Mailbox transport of the in-process master (SOEM's ethercatmain mbxsend/mbxreceive): SM0 out, SM1 in.

CoE and FoE (:mod:`~gatewaylab.hosts.ethercat.coe`, :mod:`~gatewaylab.hosts.ethercat.foe`) ride on it.
"""

from __future__ import annotations

from collections.abc import Callable

from gatewaylab.ethercat.datagram import Command
from gatewaylab.ethercat.errors import FrameFormatError, MasterError
from gatewaylab.ethercat.esc import REG_SM
from gatewaylab.ethercat.mailbox import MailboxMessage, MailboxType, decode_mailbox, encode_mailbox
from gatewaylab.hosts.ethercat.base import Port
from gatewaylab.hosts.ethercat.config import Configuration

__all__ = ["MAILBOX_POLL", "Mailboxes"]


#: Seconds between two polls of a mailbox that is not ready yet (SM1 empty, SM0 still full).
MAILBOX_POLL = 0.0005


class Mailboxes:
    """Writes requests into a slave's SM0 and reads its replies from SM1, polling on the clock until ready."""

    def __init__(self, port: Port, config: Configuration) -> None:
        self.port = port
        self.config = config

    def send(self, position: int, mtype: int, data: bytes) -> None:
        """Write one message into the slave's SM0 (waiting while it is still full), with the next counter."""
        s = self.config.slave(position)
        mo, mos = s.mailbox_out
        s.mbx_counter = s.mbx_counter % 7 + 1
        raw = encode_mailbox(MailboxMessage(mtype, data, s.mbx_counter))
        if len(raw) > mos:
            raise MasterError(f"mailbox message of {len(raw)} bytes exceeds {mos}")
        padded = raw.ljust(mos, b"\0")
        port = self.port
        port.wait_until(lambda: port.phys(Command.FPWR, s.station, mo, padded).wkc == 1, MAILBOX_POLL)

    def exchange(self, position: int, mtype: int, data: bytes,
                 accept: Callable[[MailboxMessage], bool] | None = None) -> MailboxMessage:
        """Write a request into SM0 and return the first reply of the same type from SM1: the carrier of CoE and FoE."""
        self.send(position, mtype, data)

        def wanted(m: MailboxMessage) -> bool:
            return m.type == MailboxType.ERROR or (m.type == mtype and (accept is None or accept(m)))

        msg = self.receive(position, wanted)
        if msg.type == MailboxType.ERROR:
            raise FrameFormatError(f"mailbox error reply {msg.data.hex()}")
        return msg

    def receive(self, position: int, accept: Callable[[MailboxMessage], bool]) -> MailboxMessage:
        """The next message from SM1 that ``accept`` takes; messages it refuses are read and dropped."""
        s = self.config.slave(position)
        mi, mis = s.mailbox_in
        port = self.port
        out: list[MailboxMessage] = []

        def poll() -> bool:
            if not port.fprd(s.station, REG_SM + 8 + 5, 1)[0] & 0x08:
                return False
            d = port.phys(Command.FPRD, s.station, mi, bytes(mis))
            if d.wkc != 1:
                return False
            m = decode_mailbox(d.data)
            if accept(m):
                out.append(m)
                return True
            return False

        port.wait_until(poll, MAILBOX_POLL)
        return out[0]
