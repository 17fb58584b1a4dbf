"""The IgH package's CiA402 protocol layer (manual 15.1, 15.5.4) on the MCAN Port.

An axis table (slave, MCAN channel, node id, step per motion cycle); NMT for all axes; CSP
configuration of each drive's PDOs by SDO through the gateway (RPDO1 controlword + target position,
TPDO1 statusword + actual position, both synchronous, heartbeat, mode 8); reading the actual
positions; enabling all (controlword 6 -> 7 -> 15 by RPDO, following the statusword); every cycle
the TPDO / SDO / heartbeat / EMCY frames are processed and the targets sent with a SYNC per bus,
optionally scheduled after SYNC0 (8.4). SDO transfers use the project's sans-I/O
:class:`~gatewaylab.canopen.sdo_client.SdoClient`, one per CAN bus, fed from the Port.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from gatewaylab.bus.frame import CanFrame
from gatewaylab.canopen.sdo_client import SdoClient
from gatewaylab.common.errors import LocalError, TimeoutError_
from gatewaylab.devices.ecanlite.stream import CanPacket
from gatewaylab.hosts.ecanlite.port import McanPort, RxFrame
from gatewaylab.od import SdoAbort

__all__ = ["Axis", "AxisResult", "Cia402", "NmtCommand", "parse_axes"]

_RPDO1 = struct.Struct("<Hi")
_TPDO1 = struct.Struct("<Hi")
_I32 = struct.Struct("<i")

#: CiA 402 modes of operation (0x6060): cyclic synchronous position.
MODE_CSP = 8


class NmtCommand:
    """NMT command specifiers (CiA 301 7.2.8.3.1)."""

    START = 0x01
    STOP = 0x02
    PRE_OPERATIONAL = 0x80
    RESET_NODE = 0x81
    RESET_COMMUNICATION = 0x82


@dataclass(frozen=True, slots=True)
class Axis:
    """One row of the axis table (``igh_cia402_axis_init``): where the drive is and how it moves."""

    slave: int
    channel: int
    node_id: int
    step: int = 0

    def __post_init__(self) -> None:
        if not 1 <= self.node_id <= 127:
            raise LocalError(f"node id {self.node_id} is not 1..127")
        if not 0 <= self.channel <= 3:
            raise LocalError(f"MCAN channel {self.channel} is not 0..3")


def parse_axes(text: str, default_step: int = 0) -> list[Axis]:
    """``SLAVE:CHANNEL:NODE[:STEP]`` separated by commas, e.g. ``0:0:1,0:1:2:50``."""
    axes = []
    for part in filter(None, (p.strip() for p in text.split(","))):
        fields = part.split(":")
        if len(fields) not in (3, 4):
            raise LocalError(f"axis {part!r} is not SLAVE:CHANNEL:NODE[:STEP]")
        try:
            nums = [int(f, 0) for f in fields]
        except ValueError:
            raise LocalError(f"axis {part!r}: not numbers") from None
        axes.append(Axis(nums[0], nums[1], nums[2], nums[3] if len(nums) == 4 else default_step))
    if not axes:
        raise LocalError("no axes given")
    return axes


@dataclass(slots=True)
class _AxisState:
    axis: Axis
    statusword: int = 0
    actual: int | None = None
    start: int = 0
    target: int = 0
    enable: bool = False
    fault_toggle: bool = False
    tpdos: int = 0
    heartbeats: int = 0
    nmt_state: int = -1
    emcys: list[int] = field(default_factory=list)


@dataclass(frozen=True, slots=True)
class AxisResult:
    """What the demos print per axis (15.6)."""

    slave: int
    channel: int
    node_id: int
    start: int
    target: int
    actual: int
    statusword: int
    enabled: bool
    tpdos: int
    heartbeats: int
    emcys: int

    @property
    def error(self) -> int:
        """Following error: target minus actual position (increments)."""
        return self.target - self.actual

    def reached(self, window: int = 10) -> bool:
        """Enabled and within ``window`` increments of the target (0x6067 default 10)."""
        return self.enabled and abs(self.error) <= window


class Cia402:
    """CiA 402 axes in CSP behind ECAN-Lite channels (``igh_cia402_context_init``)."""

    def __init__(self, port: McanPort, axes: Sequence[Axis], *, sdo_timeout: float = 0.5,
                 heartbeat_ms: int = 100, motion_div: int = 1) -> None:
        if not axes:
            raise LocalError("no axes")
        if motion_div < 1:
            raise LocalError("motion_div must be >= 1")
        seen = set()
        for a in axes:
            if not 0 <= a.slave < port.adapter.slave_count:
                raise LocalError(f"axis node {a.node_id}: no adapter slave {a.slave}")
            if (a.slave, a.channel, a.node_id) in seen:
                raise LocalError(f"node {a.node_id} twice on slave {a.slave} channel {a.channel}")
            seen.add((a.slave, a.channel, a.node_id))
        self.port = port
        self.adapter = port.adapter
        self.clock = port.clock
        self.axes = [_AxisState(a) for a in axes]
        self.heartbeat_ms = heartbeat_ms
        self.motion_div = motion_div
        self.buses = sorted({(a.slave, a.channel) for a in axes})
        self._sdo: dict[tuple[int, int], SdoClient] = {
            bus: SdoClient(self.clock, self._sender(*bus), timeout=sdo_timeout) for bus in self.buses}
        self._by_cob: dict[tuple[int, int, int], _AxisState] = {}
        for st in self.axes:
            a = st.axis
            for base in (0x180, 0x700, 0x080):
                self._by_cob[(a.slave, a.channel, base + a.node_id)] = st
        self.pdo_active = False
        self.sched_rpdo_ns: int | None = None
        self.sched_sync_ns: int | None = None
        self.cycle_count = 0
        # SYNC is the same packet every cycle: built once per bus (packets are frozen).
        self._sync = {(slave, channel): CanPacket.of(channel, 0x080) for slave, channel in self.buses}
        self.sdo_errors = 0
        self.other_frames = 0

    def _sender(self, slave: int, channel: int) -> Callable[[CanFrame], None]:
        def send(frame: CanFrame) -> None:
            self.port.send_frame(slave, channel, frame)
        return send

    # ------------------------------------------------------------------ the cycle
    def process_rx(self, frames: Sequence[RxFrame] | None = None) -> None:
        """``igh_cia402_process_rx``: TPDO1, SDO answers, heartbeat and EMCY of every axis."""
        for rx in self.port.receive() if frames is None else frames:
            f = rx.frame
            client = self._sdo.get((rx.slave, rx.channel))
            if 0x580 < f.can_id < 0x600 and client is not None:
                client.on_frame(f, rx.time)
                continue
            st = self._by_cob.get((rx.slave, rx.channel, f.can_id))
            if st is None:
                self.other_frames += 1
                continue
            base = f.can_id - st.axis.node_id
            if base == 0x180 and len(f.data) >= 6:
                st.statusword, st.actual = _TPDO1.unpack_from(f.data)
                st.tpdos += 1
            elif base == 0x700 and f.data:
                st.nmt_state = f.data[0] & 0x7F
                st.heartbeats += 1
            elif base == 0x080 and len(f.data) >= 2:
                st.emcys.append(int.from_bytes(f.data[:2], "little"))

    def _controlword(self, st: _AxisState) -> int:
        """The next controlword toward 'operation enabled' (CiA 402 FSA) from the last statusword."""
        sw = st.statusword
        if not st.enable:
            return 0x0000
        if sw & 0x4F == 0x08:                 # fault: reset on a 0->1 edge of bit 7
            st.fault_toggle = not st.fault_toggle
            return 0x0080 if st.fault_toggle else 0x0000
        if sw & 0x6F == 0x21:                 # ready to switch on
            return 0x0007
        if sw & 0x6F in (0x23, 0x27):         # switched on / operation enabled
            return 0x000F
        return 0x0006                         # switch on disabled and the rest: shutdown

    def send_targets_all(self) -> None:
        """``igh_cia402_send_targets_all``: RPDO1 (controlword, target) of every axis, then SYNC per bus."""
        for st in self.axes:
            a = st.axis
            data = _RPDO1.pack(self._controlword(st), st.target)
            if self.sched_rpdo_ns is not None:
                self.port.schedule_can(a.slave, a.channel, 0x200 + a.node_id, data, offset_ns=self.sched_rpdo_ns,
                                       tag=a.node_id)
            else:
                self.port.send_can(a.slave, a.channel, 0x200 + a.node_id, data)
        for slave, channel in self.buses:
            if self.sched_sync_ns is not None:
                self.port.schedule_can(slave, channel, 0x080, b"", offset_ns=self.sched_sync_ns)
            else:
                self.port.send_packet(slave, self._sync[(slave, channel)])

    def send_target_step(self) -> None:
        """``igh_cia402_send_target_step``: every enabled axis advances by its step, then targets go out."""
        for st in self.axes:
            if self.enabled(st):
                st.target += st.axis.step
        self.send_targets_all()

    def set_scheduled_tx(self, rpdo_offset_ns: int | None, sync_offset_ns: int | None = None) -> None:
        """``igh_cia402_set_scheduled_tx``: RPDOs and SYNC at SYNC0 + offset (8.4); needs DC SYNC0 on."""
        if (rpdo_offset_ns is not None or sync_offset_ns is not None) and not self.adapter.config.dc_sync0:
            raise LocalError("scheduled transmit needs DC SYNC0 (15.5.4 step 6)")
        self.sched_rpdo_ns = rpdo_offset_ns
        self.sched_sync_ns = sync_offset_ns

    def cycle(self, move: bool = False) -> None:
        """One EtherCAT cycle: receive, process, (every ``motion_div`` cycles) targets + SYNC, send, wait."""
        port = self.port
        port.cycle_begin()
        self.process_rx()
        if self.pdo_active and self.cycle_count % self.motion_div == 0:
            if move and self.adapter.domain_complete:
                self.send_target_step()
            else:
                self.send_targets_all()     # 15.5.2 step 8: domain incomplete -> hold the targets
        self.cycle_count += 1
        port.cycle_end()
        self.adapter.wait_period()

    def _wait(self, done: Callable[[], bool], timeout: float, what: str) -> None:
        deadline = self.clock.now() + timeout
        while not done():
            if self.clock.now() >= deadline:
                raise TimeoutError_(f"{what}: not done within {timeout:g} s")
            self.cycle()

    # ------------------------------------------------------------------ startup
    def send_nmt_all(self, command: int = NmtCommand.START) -> None:
        """``igh_cia402_send_nmt_all``: one NMT command per bus to each axis's node (0x000)."""
        for st in self.axes:
            a = st.axis
            self.port.send_can(a.slave, a.channel, 0x000, bytes((command, a.node_id)))
        self.cycle()

    def sdo_transfer(self, requests: Sequence[tuple[Axis, int, int, bytes | None]], timeout: float) -> list[bytes]:
        """Run SDO uploads (data None) and downloads through the gateway, in parallel per node; raises
        :class:`SdoAbort` with the first abort, :class:`TimeoutError_` when they do not finish."""
        results: list[bytes | SdoAbort | None] = [None] * len(requests)
        done = [False] * len(requests)

        def callback(i: int) -> Callable[[bytes | SdoAbort | None], None]:
            def cb(result: bytes | SdoAbort | None) -> None:
                results[i] = result
                done[i] = True
            return cb

        for i, (a, index, sub, data) in enumerate(requests):
            client = self._sdo[(a.slave, a.channel)]
            if data is None:
                client.upload(a.node_id, index, sub, callback(i))
            else:
                client.download(a.node_id, index, sub, data, callback(i))
        self._wait(lambda: all(done), timeout, f"{len(requests)} SDO transfers")
        out = []
        for (a, index, sub, _), r in zip(requests, results, strict=True):
            if isinstance(r, SdoAbort):
                self.sdo_errors += 1
                raise SdoAbort(r.code, f"node {a.node_id} 0x{index:04X}:{sub:02X}")
            out.append(r if isinstance(r, bytes) else b"")
        return out

    def configure_csp_all(self, timeout: float = 5.0) -> None:
        """``igh_cia402_configure_csp_all_timeout``: PDO mapping, heartbeat and mode 8 by SDO."""
        reqs: list[tuple[Axis, int, int, bytes | None]] = []
        u8, u16, u32 = struct.Struct("<B").pack, struct.Struct("<H").pack, struct.Struct("<I").pack
        for st in self.axes:
            a = st.axis
            n = a.node_id
            reqs += [(a, 0x1400, 1, u32(0x80000200 + n)), (a, 0x1600, 0, u8(0)),
                     (a, 0x1600, 1, u32(0x60400010)), (a, 0x1600, 2, u32(0x607A0020)), (a, 0x1600, 0, u8(2)),
                     (a, 0x1400, 2, u8(1)), (a, 0x1400, 1, u32(0x200 + n)),
                     (a, 0x1800, 1, u32(0x80000180 + n)), (a, 0x1A00, 0, u8(0)),
                     (a, 0x1A00, 1, u32(0x60410010)), (a, 0x1A00, 2, u32(0x60640020)), (a, 0x1A00, 0, u8(2)),
                     (a, 0x1800, 2, u8(1)), (a, 0x1800, 1, u32(0x180 + n)),
                     (a, 0x1017, 0, u16(self.heartbeat_ms)), (a, 0x6060, 0, u8(MODE_CSP)),
                     (a, 0x6061, 0, None)]
        results = self.sdo_transfer(reqs, timeout)
        per_axis = len(reqs) // len(self.axes)
        for i, st in enumerate(self.axes):
            mode = results[(i + 1) * per_axis - 1]
            if mode[:1] != bytes((MODE_CSP,)):
                raise LocalError(f"node {st.axis.node_id}: mode display {mode.hex()} after writing CSP (8)")

    def request_actual_position_all(self, timeout: float = 2.0) -> list[int]:
        """``igh_cia402_request_actual_position_all_timeout``: 0x6064 of every axis; targets start there."""
        values = self.sdo_transfer([(st.axis, 0x6064, 0, None) for st in self.axes], timeout)
        out = []
        for st, raw in zip(self.axes, values, strict=True):
            pos = _I32.unpack(raw[:4].ljust(4, b"\0"))[0]
            st.actual = st.start = st.target = pos
            out.append(pos)
        return out

    def start_pdos(self) -> None:
        """NMT start for all and begin the RPDO + SYNC stream (targets = actual positions)."""
        self.send_nmt_all(NmtCommand.START)
        self.pdo_active = True

    @staticmethod
    def enabled(st: _AxisState) -> bool:
        """Statusword says 'operation enabled' (CiA 402 state machine)."""
        return st.statusword & 0x6F == 0x27

    def enable_all(self, timeout: float = 2.0) -> None:
        """``igh_cia402_enable_all``: controlword 6 -> 7 -> 15 until every axis is operation enabled."""
        if not self.pdo_active:
            self.start_pdos()
        for st in self.axes:
            st.enable = True
        self._wait(lambda: all(self.enabled(st) for st in self.axes), timeout, "enable all axes")
        for st in self.axes:          # motion starts where the axis is now
            if st.actual is not None:
                st.start = st.target = st.actual

    def startup(self, *, configure: bool = True, timeout: float = 5.0) -> None:
        """The startup of 15.5.4 step 4: NMT, CSP configuration, actual positions, enable."""
        self.send_nmt_all(NmtCommand.PRE_OPERATIONAL)
        if configure:
            self.configure_csp_all(timeout)
        self.request_actual_position_all(timeout)
        self.start_pdos()
        self.enable_all(timeout)

    def run(self, cycles: int, progress: Callable[[int], None] | None = None) -> None:
        """``cycles`` motion cycles, every enabled axis advancing by its step per motion cycle."""
        for i in range(cycles):
            self.cycle(move=True)
            if progress is not None:
                progress(i + 1)

    def settle(self, timeout: float = 1.0, window: int = 10, window_time: float = 0.005) -> bool:
        """Hold the targets until every axis has stayed within ``window`` for ``window_time``
        (0x6067 / 0x6068 defaults: 10 inc, 5 ms), or ``timeout`` passes."""
        since: list[float | None] = [None]

        def inside() -> bool:
            now = self.clock.now()
            if not all(r.reached(window) for r in self.results()):
                since[0] = None
                return False
            first = since[0]
            if first is None:
                since[0] = first = now
            return now - first >= window_time

        try:
            self._wait(inside, timeout, "settle")
        except TimeoutError_:
            return False
        return True

    def disable_all(self, cycles: int = 5) -> None:
        """Controlword 0 (disable voltage) for a few cycles: a safe stop before leaving OP."""
        for st in self.axes:
            st.enable = False
        for _ in range(cycles):
            self.cycle()

    def results(self) -> list[AxisResult]:
        """Per-axis results (15.6 demos' summary)."""
        return [AxisResult(st.axis.slave, st.axis.channel, st.axis.node_id, st.start, st.target,
                           st.actual if st.actual is not None else 0, st.statusword, self.enabled(st), st.tpdos,
                           st.heartbeats, len(st.emcys)) for st in self.axes]
