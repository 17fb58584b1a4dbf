"""FoE of the in-process master (SOEM's ethercatfoe): file read and write through the mailbox."""

from __future__ import annotations

from gatewaylab.common.errors import TimeoutError_
from gatewaylab.ethercat.errors import FoeError
from gatewaylab.ethercat.foe import FOE_HEADER, FoeOpcode, foe_packet
from gatewaylab.ethercat.mailbox import MailboxType
from gatewaylab.hosts.ethercat.config import Configuration
from gatewaylab.hosts.ethercat.mailbox import Mailboxes

__all__ = ["FOE_BUSY_RETRY", "Foe"]


#: Seconds before an FoE data packet that the slave answered with BUSY is sent again.
FOE_BUSY_RETRY = 0.01


class Foe:
    """The FoE client of one master: files by slave position, with BUSY retries on the clock."""

    def __init__(self, mailbox: Mailboxes, config: Configuration) -> None:
        self.mailbox = mailbox
        self.config = config
        #: Seconds a slave may keep answering BUSY to one data packet before TimeoutError_.
        self.busy_timeout = 10.0

    def _foe(self, position: int, packet: bytes) -> tuple[int, int, bytes]:
        """One FoE request and the (opcode, packet number or error code, data) of its reply."""
        msg = self.mailbox.exchange(position, MailboxType.FOE, packet)
        opcode, _r, word = FOE_HEADER.unpack_from(msg.data, 0)
        rest = msg.data[FOE_HEADER.size:]
        if opcode == FoeOpcode.ERR:
            raise FoeError(rest.decode("latin-1", "replace"), word)
        return opcode, word, rest

    def write(self, position: int, name: str, data: bytes, password: int = 0) -> None:
        """Send a file by FoE (firmware updates), repeating a packet while the slave answers BUSY."""
        clock = self.mailbox.port.clock
        max_data = self.config.slave(position).mailbox_out[1] - 12
        opcode, word, _ = self._foe(position, foe_packet(FoeOpcode.WRQ, password, name.encode("latin-1")))
        if opcode != FoeOpcode.ACK or word != 0:
            raise FoeError("write request not acknowledged", 0x8000)
        packet = 0
        pos = 0
        while True:
            chunk = data[pos:pos + max_data]
            pos += len(chunk)
            packet += 1
            opcode, word, _ = self._foe(position, foe_packet(FoeOpcode.DATA, packet, chunk))
            deadline = clock.now() + self.busy_timeout
            while opcode == FoeOpcode.BUSY:  # the slave needs time: repeat the packet later
                if clock.now() >= deadline:
                    raise TimeoutError_("FoE slave stayed busy")
                clock.wait(FOE_BUSY_RETRY)
                opcode, word, _ = self._foe(position, foe_packet(FoeOpcode.DATA, packet, chunk))
            if opcode != FoeOpcode.ACK or word != packet:
                raise FoeError(f"data packet {packet} not acknowledged", 0x8005)
            if len(chunk) < max_data:
                return

    def read(self, position: int, name: str, password: int = 0) -> bytes:
        """Read a file by FoE (logs, configuration), acknowledging every data packet."""
        max_data = self.config.slave(position).mailbox_in[1] - 12
        out = bytearray()
        opcode, word, rest = self._foe(position, foe_packet(FoeOpcode.RRQ, password, name.encode("latin-1")))
        while True:
            if opcode != FoeOpcode.DATA:
                raise FoeError(f"unexpected FoE opcode {opcode}", 0x8004)
            out += rest
            if len(rest) < max_data:
                # the last ACK has no reply: send it without waiting for one
                self.mailbox.send(position, MailboxType.FOE, foe_packet(FoeOpcode.ACK, word))
                return bytes(out)
            opcode, word, rest = self._foe(position, foe_packet(FoeOpcode.ACK, word))
