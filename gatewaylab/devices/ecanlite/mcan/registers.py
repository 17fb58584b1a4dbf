"""The MCAN register service (manual 13.5 / 13.6, Bosch M_CAN 3.x layout as in the HPM MCAN):
register offsets, IR bits, what a channel's registers read, and the whitelisted writes that
re-program a running channel. Reads are computed from the channel's applied configuration, its
bus controller and its data path; nothing here keeps state of its own.
"""

from __future__ import annotations

from dataclasses import replace
from types import MappingProxyType
from typing import TYPE_CHECKING

from gatewaylab.bus.controller import ErrorKind, ErrorState
from gatewaylab.common.errors import GatewaylabError
from gatewaylab.devices.ecanlite import bittiming
from gatewaylab.devices.ecanlite.bittiming import BitTimingError, Tdc
from gatewaylab.devices.ecanlite.mcan.layout import ChannelRuntime, NodeMode

if TYPE_CHECKING:
    from gatewaylab.devices.ecanlite.mcan.channel import McanChannel

__all__ = ["LEC", "PROGRAMMING", "REG", "WRITE_WHITELIST", "read_register", "reprogram", "write_register"]


# M_CAN register offsets (HPM MCAN = Bosch M_CAN 3.x) the register service knows.
REG = MappingProxyType({
    "ENDN": 0x0004, "DBTP": 0x000C, "TEST": 0x0010, "RWD": 0x0014, "CCCR": 0x0018, "NBTP": 0x001C,
    "TSCC": 0x0020, "TSCV": 0x0024, "TOCC": 0x0028, "TOCV": 0x002C, "ECR": 0x0040, "PSR": 0x0044,
    "TDCR": 0x0048, "IR": 0x0050, "IE": 0x0054, "ILS": 0x0058, "ILE": 0x005C, "GFC": 0x0080,
    "SIDFC": 0x0084, "XIDFC": 0x0088, "XIDAM": 0x0090, "HPMS": 0x0094, "RXF0C": 0x00A0, "RXF0S": 0x00A4,
    "RXF0A": 0x00A8, "RXBC": 0x00AC, "RXF1C": 0x00B0, "RXF1S": 0x00B4, "RXF1A": 0x00B8, "RXESC": 0x00BC,
    "TXBC": 0x00C0, "TXFQS": 0x00C4, "TXESC": 0x00C8, "TXBRP": 0x00CC, "TXBAR": 0x00D0, "TXBCR": 0x00D4,
    "TXBTO": 0x00D8, "TXBCF": 0x00DC, "TXEFC": 0x00F0, "TXEFS": 0x00F4, "TXEFA": 0x00F8,
})
#: 13.6 write whitelist.
WRITE_WHITELIST = frozenset({0x000C, 0x0010, 0x0014, 0x0018, 0x001C, 0x0048, 0x0050, 0x0054, 0x0058,
                         0x005C, 0x0080, 0x0090, 0x00A8, 0x00B8, 0x00D0, 0x00D4, 0x00F8})
# IR bits (M_CAN): RF0N 0, RF0F 2, RF0L 3, TC 9, TFE 11, PEA 27, PED 28, EP 23, EW 24, BO 25.
IR_RF0N, IR_RF0F, IR_RF0L, IR_HPM, IR_TC, IR_TFE = 1 << 0, 1 << 2, 1 << 3, 1 << 8, 1 << 9, 1 << 11
IR_RF1N, IR_RF1F, IR_RF1L = 1 << 4, 1 << 6, 1 << 7
#: IR new message / full / lost bits of FIFO0 and FIFO1 (RX buffers: DRX 19, no full/lost bits).
IR_NEW, IR_FULL, IR_LOST = (IR_RF0N, IR_RF1N, 1 << 19), (IR_RF0F, IR_RF1F, 0), (IR_RF0L, IR_RF1L, 0)
IR_EP, IR_EW, IR_BO, IR_PEA, IR_PED = 1 << 23, 1 << 24, 1 << 25, 1 << 27, 1 << 28
#: PSR.LEC of an error kind: 2 form, 3 ack, 5 bit0, 6 crc.
LEC = {ErrorKind.FORM: 2, ErrorKind.ACK: 3, ErrorKind.BIT: 5, ErrorKind.CRC: 6}

def read_register(ch: McanChannel, offset: int) -> int:
    """Read an MCAN register of channel ``ch`` (offsets of :data:`REG`; others read 0)."""
    if offset in ch.expert:
        return ch.expert[offset]
    c = ch.controller
    rt = ch.runtime
    tec = c.tec if c is not None else 0
    rec = c.rec if c is not None else 0
    if offset == 0x0004:
        return 0x87654321
    if offset == 0x0040:      # ECR: TEC 0..7, REC 8..14, RP 15, CEL 16..23
        return (min(tec, 255) | min(rec, 127) << 8 | (rec > 127) << 15 | ch.path.counters.error_log << 16)
    if offset == 0x0044:      # PSR: LEC 0..2, ACT 3..4 (1 idle), EP 5, EW 6, BO 7
        state = c.state if c is not None else ErrorState.ERROR_ACTIVE
        return (ch.lec | 1 << 3 | (state is ErrorState.ERROR_PASSIVE) << 5
                | (tec >= 96 or rec >= 96) << 6 | (state is ErrorState.BUS_OFF) << 7)
    if offset == 0x0050:
        ir = ch.path.ir
        if c is not None:
            ir |= (c.state is ErrorState.ERROR_PASSIVE) * IR_EP | (c.state is ErrorState.BUS_OFF) * IR_BO
        if not ch.path.tx:
            ir |= IR_TFE
        return ir
    if rt is None:
        return 0
    if offset == 0x001C:      # NBTP: NSJW 25..31, NBRP 16..24, NTSEG1 8..15, NTSEG2 0..6 (value - 1)
        n = rt.nominal
        return (n.sjw - 1) << 25 | (n.brp - 1) << 16 | (n.tseg1 - 1) << 8 | (n.tseg2 - 1)
    if offset == 0x000C:      # DBTP: TDC 23, DBRP 16..20, DTSEG1 8..12, DTSEG2 4..7, DSJW 0..3
        d = rt.data
        if d is None:
            return 0
        return ((rt.tdc is not None and rt.tdc.enabled) << 23 | (d.brp - 1) << 16 | (d.tseg1 - 1) << 8
                | (d.tseg2 - 1) << 4 | (d.sjw - 1))
    if offset == 0x0048:
        return 0 if rt.tdc is None else rt.tdc.offset << 8 | rt.tdc.filter
    if offset == 0x0018:      # CCCR: INIT 0, MON 5, DAR 6, TEST 7, FDOE 8, BRSE 9, TXP 14, NISO 15
        return (int(c is not None and c.state is ErrorState.BUS_OFF)
                | (rt.node_mode in (NodeMode.LISTEN, NodeMode.INTERNAL_LOOPBACK)) << 5
                | (not rt.auto_retransmit) << 6 | (rt.node_mode is NodeMode.INTERNAL_LOOPBACK) << 7
                | rt.fd << 8 | rt.fd << 9 | rt.transmit_pause << 14 | rt.non_iso << 15
                | (rt.node_mode is NodeMode.RESTRICTED) << 2)
    if offset == 0x0010:
        return (rt.node_mode is NodeMode.INTERNAL_LOOPBACK) << 4
    if offset == 0x0080:      # GFC: RRFE 0, RRFS 1, ANFE 2..3, ANFS 4..5
        return (rt.reject_remote_ext | rt.reject_remote_std << 1 | rt.non_match_ext << 2
                | rt.non_match_std << 4)
    if offset == 0x0084:
        return len(rt.std_filters) << 16
    if offset == 0x0088:
        return len(rt.ext_filters) << 16
    if offset == 0x0090:
        return rt.xidam
    if offset == 0x0094:
        return ch.hpms
    if offset in (0x00A0, 0x00B0):      # RXFnC: FnS 16..22, FnOM 31
        fifo = int(offset == 0x00B0)
        return rt.rx_sizes[fifo] << 16 | rt.rx_overwrite[fifo] << 31
    if offset in (0x00A4, 0x00B4):      # RXFnS: FnFL 0..6, FnF 24, RFnL 25
        fifo = int(offset == 0x00B4)
        fill = ch.path.fill[fifo]
        full = fill >= rt.rx_sizes[fifo] or (fifo == 0 and len(ch.path.rx) >= ch.path.depth)
        return min(fill, 127) | full << 24 | ch.path.lost[fifo] << 25
    if offset == 0x00C0:      # TXBC: NDTB 16..21, TFQS 24..29, TFQM 30
        return (rt.tx_elements << 24) | rt.tx_queue_mode << 30
    if offset == 0x00C4:      # TXFQS: TFFL 0..5, TFQF 21
        free = max(0, rt.tx_elements - len(ch.path.tx))
        return free | (free == 0) << 21
    if offset == 0x00F0:
        return rt.tx_event_fifo << 16
    return 0


def write_register(ch: McanChannel, offset: int, value: int) -> bool:
    """A whitelisted write (13.6); False = the channel cannot take this value (status 2).

    IR is write-1-to-clear. NBTP, DBTP, TDCR, CCCR, TEST, GFC and XIDAM re-program the running
    channel as the M_CAN register would (bit timing re-times the bus controller, CCCR/TEST set
    the node mode, FD, retransmission, GFC/XIDAM the global filter); 0x800x keeps the requested
    configuration, and its next apply (or a reset) programs that again. The other whitelisted
    registers (interrupt routing, acknowledges, TX buffer requests) are kept and read back."""
    value &= 0xFFFFFFFF
    if offset == 0x0050:
        ch.path.ir &= ~value
        if value & IR_RF0L:
            ch.path.lost[0] = False
        if value & IR_RF1L:
            ch.path.lost[1] = False
        return True
    if offset not in PROGRAMMING:
        ch.expert[offset] = value
        return True
    rt = ch.runtime
    if rt is None:
        return False          # nothing applied yet: no running channel to re-program
    try:
        new = reprogram(rt, offset, value)
    except BitTimingError:
        return False
    try:
        ch.activate(new)
    except GatewaylabError:
        ch.activate(rt)
        return False
    ch.runtime = new
    return True


#: Registers whose write re-programs the running channel (13.6 whitelist, M_CAN layout).
PROGRAMMING = frozenset({0x000C, 0x0010, 0x0018, 0x001C, 0x0048, 0x0080, 0x0090})


def reprogram(rt: ChannelRuntime, offset: int, v: int) -> ChannelRuntime:
    """The runtime after an M_CAN register write (fields as Bosch M_CAN: value - 1 encodings);
    BitTimingError when the channel cannot run it."""
    if offset == 0x001C:      # NBTP: NSJW 25..31, NBRP 16..24, NTSEG1 8..15, NTSEG2 0..6
        nominal = bittiming.manual((v >> 16 & 0x1FF) + 1, (v >> 8 & 0xFF) + 1, (v & 0x7F) + 1, (v >> 25) + 1)
        return replace(rt, nominal=nominal)
    if offset == 0x000C:      # DBTP: TDC 23, DBRP 16..20, DTSEG1 8..12, DTSEG2 4..7, DSJW 0..3
        data = bittiming.manual((v >> 16 & 0x1F) + 1, (v >> 8 & 0x1F) + 1, (v >> 4 & 0xF) + 1, (v & 0xF) + 1,
                                bittiming.DATA, what="data")
        auto = bittiming.tdc(bool(v >> 23 & 1), data)
        old = rt.tdc
        tdc = Tdc(auto.enabled, old.offset if old else auto.offset, old.filter if old else auto.filter)
        return replace(rt, data=data, tdc=tdc)
    if offset == 0x0048:      # TDCR: TDCF 0..6, TDCO 8..14
        if rt.data is None:
            raise BitTimingError("TDCR needs a CAN FD data phase")
        enabled = rt.tdc.enabled if rt.tdc is not None else rt.data.bitrate >= bittiming.TDC_FORCED_BITRATE
        return replace(rt, tdc=Tdc(enabled, v >> 8 & 0x7F, v & 0x7F))
    if offset == 0x0018:      # CCCR: ASM 2, MON 5, DAR 6, TEST 7, FDOE 8, TXP 14, NISO 15
        fd = bool(v >> 8 & 1)
        if fd and rt.data is None:
            raise BitTimingError("FDOE without a data bit timing (write DBTP first)")
        loopback = bool(v >> 7 & 1) and rt.node_mode is NodeMode.INTERNAL_LOOPBACK
        mode = (NodeMode.INTERNAL_LOOPBACK if loopback else NodeMode.LISTEN if v >> 5 & 1
                else NodeMode.RESTRICTED if v >> 2 & 1 else NodeMode.NORMAL)
        return replace(rt, fd=fd, node_mode=mode, auto_retransmit=not v >> 6 & 1,
                       transmit_pause=bool(v >> 14 & 1), non_iso=bool(v >> 15 & 1))
    if offset == 0x0010:      # TEST: LBCK 4 (internal loopback; CCCR.TEST/MON are implied)
        if v >> 4 & 1:
            return replace(rt, node_mode=NodeMode.INTERNAL_LOOPBACK)
        return replace(rt, node_mode=NodeMode.NORMAL) if rt.node_mode is NodeMode.INTERNAL_LOOPBACK else rt
    if offset == 0x0080:      # GFC: RRFE 0, RRFS 1, ANFE 2..3, ANFS 4..5
        return replace(rt, reject_remote_ext=bool(v & 1), reject_remote_std=bool(v >> 1 & 1),
                       non_match_ext=v >> 2 & 3, non_match_std=v >> 4 & 3)
    return replace(rt, xidam=v & 0x1FFFFFFF)      # XIDAM

