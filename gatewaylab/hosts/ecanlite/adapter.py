"""The IgH package's adapter layer (manual 15.1, 15.5.2, 15.5.3) on a :class:`MasterBackend`.

Slaves and their positions, a PDO multiplier per slave, the startup-SDO queue written in PREOP
(5.4.3 phase B 0x1C12/0x1C13, phase C 0x8010/0x8011, phase D readback checks, then whatever the
MCAN Port appends: phase E 0x8001..0x8004), DC SYNC0 with cycle and shift, wait-for-OP with a
timeout, the raw RxPDO/TxPDO buffers of each slave, and the working-counter / domain-complete
check of every cycle (15.5.2 step 8). The same code runs on ``InProcessBackend`` (simulated clock)
and ``PysoemBackend`` (a real line).
"""

from __future__ import annotations

import bisect
import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

from gatewaylab.common.errors import LocalError, ProtocolError
from gatewaylab.devices.ecanlite.image import PRODUCT_CODE, RX_MAP, RX_PROFILE, TX_MAP, TX_PROFILE, VENDOR_ID
from gatewaylab.devices.ecanlite.stream import Direction, StreamLayout
from gatewaylab.ethercat.esc import AlState
from gatewaylab.hosts.ethercat.backend import MasterBackend, SlaveIdentity

__all__ = ["AdapterConfig", "CycleStatus", "EcanAdapter", "PeriodStats", "SlaveConfig", "StartupError",
           "StartupSdo", "find_ecanlite"]

_U8 = struct.Struct("<B")
_U16 = struct.Struct("<H")
_U32 = struct.Struct("<I")


class StartupError(ProtocolError):
    """A startup SDO was refused or its readback differs (5.4.3 phase D, 13.4 apply status)."""


@dataclass(frozen=True, slots=True)
class StartupSdo:
    """One entry of the startup queue: a download, or (``check``) an upload compared to ``data``."""

    position: int
    index: int
    subindex: int
    data: bytes
    check: bool = False
    what: str = ""

    @classmethod
    def u8(cls, position: int, index: int, sub: int, value: int, what: str = "") -> StartupSdo:
        """A one-byte download."""
        return cls(position, index, sub, _U8.pack(value), False, what)

    @classmethod
    def u16(cls, position: int, index: int, sub: int, value: int, what: str = "") -> StartupSdo:
        """A two-byte download (little-endian)."""
        return cls(position, index, sub, _U16.pack(value), False, what)

    @classmethod
    def u32(cls, position: int, index: int, sub: int, value: int, what: str = "") -> StartupSdo:
        """A four-byte download (little-endian)."""
        return cls(position, index, sub, _U32.pack(value), False, what)

    @classmethod
    def expect(cls, position: int, index: int, sub: int, data: bytes, what: str = "") -> StartupSdo:
        """An upload that must read back ``data`` (startup check)."""
        return cls(position, index, sub, data, True, what)


@dataclass(frozen=True, slots=True)
class SlaveConfig:
    """The per-slave PDO profile (0x8010 TxPDO / 0x8011 RxPDO, 5.4.2, 13.2).

    ``multiplier`` N selects the first N chunks both ways (128*N bytes, 5.2); the channel masks
    are per direction (``tx_mask`` what the slave uploads, ``rx_mask`` what the master may send).
    """

    position: int
    multiplier: int = 3
    tx_mask: int = 0x0F
    rx_mask: int = 0x0F
    profile: int = 0
    budget: int = 0
    tx_options: int = 0
    rx_options: int = 0

    @property
    def tx_layout(self) -> StreamLayout:
        """The TxPDO (0x8010) layout this configuration activates."""
        return StreamLayout(self.multiplier, self.tx_mask, self.profile, self.budget, self.tx_options,
                            Direction.TX)

    @property
    def rx_layout(self) -> StreamLayout:
        """The RxPDO (0x8011) layout this configuration activates."""
        return StreamLayout(self.multiplier, self.rx_mask, self.profile, self.budget, self.rx_options,
                            Direction.RX)


@dataclass(frozen=True, slots=True)
class AdapterConfig:
    """What ``ecan_igh_config_t`` holds (15.5.2 step 3): slaves, cycle, DC SYNC0."""

    slaves: tuple[SlaveConfig, ...]
    cycle_us: int = 1000
    dc_sync0: bool = False
    dc_cycle_us: int = 0            # 0: follows cycle_us (15.6 --dc-cycle-us)
    dc_shift_us: int = 0
    skip_sdo_config: bool = False   # 15.6 --skip-sdo-config: no startup SDOs (repeated debugging)

    @classmethod
    def for_positions(cls, positions: Sequence[int], multiplier: int = 3, **kwargs: int | bool) -> AdapterConfig:
        """Every slave with the same multiplier (``ecan_igh_config_set_pdo_multiplier``)."""
        return cls(tuple(SlaveConfig(p, multiplier) for p in positions), **kwargs)  # type: ignore[arg-type]


@dataclass(frozen=True, slots=True)
class CycleStatus:
    """One process-data cycle: working counter and whether the domain is complete (15.5.2 step 8)."""

    wkc: int
    expected: int
    time: float

    @property
    def complete(self) -> bool:
        """``ecan_igh_domain_is_complete``: every datagram reached every slave."""
        return self.wkc == self.expected


#: A master period longer than this many nominal periods counts as a late cycle.
LATE_FACTOR = 1.5


@dataclass(slots=True)
class PeriodStats:
    """master_period: time between two exchanges (13.9), in seconds."""

    samples: list[float] = field(default_factory=list)
    last: float | None = None

    def mark(self, t: float) -> None:
        """One cycle started at ``t``: records the period since the last one."""
        if self.last is not None:
            self.samples.append(t - self.last)
        self.last = t

    def summary(self, nominal: float) -> dict[str, float]:
        """min / max / mean / p99 in microseconds, the largest deviation from ``nominal`` and ``late``:
        the periods longer than LATE_FACTOR x ``nominal`` (the master missed a cycle's slot)."""
        s = sorted(self.samples)
        if not s:
            return {"count": 0, "min_us": 0.0, "max_us": 0.0, "mean_us": 0.0, "p99_us": 0.0, "max_error_us": 0.0,
                    "late": 0}
        p99 = s[min(len(s) - 1, math.ceil(0.99 * len(s)) - 1)]
        return {"count": len(s), "min_us": s[0] * 1e6, "max_us": s[-1] * 1e6, "mean_us": sum(s) / len(s) * 1e6,
                "p99_us": p99 * 1e6, "max_error_us": max(abs(s[0] - nominal), abs(s[-1] - nominal)) * 1e6,
                "late": len(s) - bisect.bisect_right(s, LATE_FACTOR * nominal)}


def find_ecanlite(backend: MasterBackend) -> list[SlaveIdentity]:
    """The ECAN-Lite slaves of the line (identity of image.py), in line order (15.5.2 step 1)."""
    return [s for s in backend.slaves() if s.vendor_id == VENDOR_ID and s.product_code == PRODUCT_CODE]


class EcanAdapter:
    """Master configuration and the raw process data of the ECAN-Lite slaves (15.1 Adapter).

    Slave *k* of the adapter is ``config.slaves[k]`` at line position ``config.slaves[k].position``.
    """

    def __init__(self, backend: MasterBackend, config: AdapterConfig) -> None:
        if not config.slaves:
            raise LocalError("the adapter needs at least one slave")
        if config.cycle_us <= 0:
            raise LocalError(f"cycle_us {config.cycle_us} must be > 0")
        positions = [s.position for s in config.slaves]
        known = {s.position for s in backend.slaves()}
        missing = [p for p in positions if p not in known]
        if missing:
            raise LocalError(f"no slave at position(s) {missing}; the line has {sorted(known)}")
        self.backend = backend
        self.clock = backend.clock
        self.config = config
        self.period = config.cycle_us * 1e-6
        self._extra: list[StartupSdo] = []
        self.cycles = 0
        self.wkc_errors = 0
        self.last: CycleStatus | None = None
        self.master_period = PeriodStats()
        self._deadline: float | None = None
        self.started = False

    # ------------------------------------------------------------------ configuration
    @property
    def slave_count(self) -> int:
        """ECAN-Lite slaves this adapter drives."""
        return len(self.config.slaves)

    def slave(self, k: int) -> SlaveConfig:
        """The configuration of adapter slave ``k``."""
        try:
            return self.config.slaves[k]
        except IndexError:
            raise LocalError(f"no adapter slave {k} (0..{self.slave_count - 1})") from None

    def set_slave(self, k: int, cfg: SlaveConfig) -> None:
        """Replace slave ``k``'s profile (the MCAN Port sets masks and options) before :meth:`start`."""
        if self.started:
            raise LocalError("the profile is fixed once started (14.2: not in OP)")
        slaves = list(self.config.slaves)
        self.slave(k)
        slaves[k] = cfg
        self.config = replace(self.config, slaves=tuple(slaves))

    def add_startup_sdo(self, sdo: StartupSdo) -> None:
        """Append to the startup queue after the profile (the Port's 0x8001..0x8004, 15.5.2 step 4)."""
        self._extra.append(sdo)

    def startup_queue(self) -> list[StartupSdo]:
        """Phase B, C, D for every slave (5.4.3), then the appended entries, in write order."""
        q: list[StartupSdo] = []
        for s in self.config.slaves:
            p = s.position
            for assign, base in ((0x1C12, RX_MAP), (0x1C13, TX_MAP)):               # phase B
                q.append(StartupSdo.u8(p, assign, 0, 0, "clear assignment"))
                q.extend(StartupSdo.u16(p, assign, i + 1, base + i, "assign chunk") for i in range(s.multiplier))
                q.append(StartupSdo.u8(p, assign, 0, s.multiplier, "assignment count"))
            for index, layout in ((TX_PROFILE, s.tx_layout), (RX_PROFILE, s.rx_layout)):   # phase C
                q.append(StartupSdo.u8(p, index, 3, layout.multiplier, "PDO size multiplier"))
                q.append(StartupSdo.u8(p, index, 4, layout.channel_mask, "channel mask"))
                q.append(StartupSdo.u8(p, index, 5, layout.profile, "encapsulation profile"))
                q.append(StartupSdo.u8(p, index, 6, int(layout.budget_policy), "budget policy"))
                q.append(StartupSdo.u8(p, index, 7, layout.options, "option flags"))
                q.append(StartupSdo.u8(p, index, 1, 1, "apply profile"))
            for index, layout in ((TX_PROFILE, s.tx_layout), (RX_PROFILE, s.rx_layout)):   # phase D
                q.append(StartupSdo.expect(p, index, 2, _U8.pack(0), "profile apply status"))
                q.append(StartupSdo.expect(p, index, 9, _U16.pack(layout.pdo_bytes), "active PDO bytes"))
                q.append(StartupSdo.expect(p, index, 10, _U16.pack(layout.frame_area_bytes), "active frame area"))
                q.append(StartupSdo.expect(p, index, 11, _U32.pack(layout.layout_crc), "active layout CRC"))
                q.append(StartupSdo.expect(p, index, 12, _U32.pack(layout.profile_word), "active profile word"))
        return q + self._extra

    def run_startup_queue(self) -> int:
        """Write the queue in PREOP; raises :class:`StartupError` naming the entry that failed."""
        b = self.backend
        n = 0
        for e in self.startup_queue():
            where = f"slave {e.position} 0x{e.index:04X}:{e.subindex:02X} ({e.what})"
            if e.check:
                got = b.sdo_upload(e.position, e.index, e.subindex)
                if got[:len(e.data)] != e.data:
                    raise StartupError(f"{where}: read {got.hex()} expected {e.data.hex()} (5.4.3 phase D)")
            else:
                try:
                    b.sdo_download(e.position, e.index, e.subindex, e.data)
                except ProtocolError as exc:
                    raise StartupError(f"{where}: {exc}") from exc
            n += 1
        return n

    # ------------------------------------------------------------------ bring-up
    def start(self, op_timeout: float = 10.0) -> None:
        """PREOP startup SDOs, mapping, DC SYNC0, SAFEOP, OP (``ecan_igh_init`` + ``wait_op``)."""
        b = self.backend
        b.request_state(AlState.PREOP)
        if not self.config.skip_sdo_config:
            self.run_startup_queue()
        b.config_map()
        for s in self.config.slaves:
            out = b.outputs(s.position)
            if len(out) != 128 * s.multiplier or len(b.inputs(s.position)) != 128 * s.multiplier:
                raise StartupError(f"slave {s.position}: mapped {len(out)} / {len(b.inputs(s.position))} bytes, "
                                   f"the profile has {128 * s.multiplier} (5.4.1)")
            out[:] = bytes(len(out))
        if self.config.dc_sync0:
            cycle = (self.config.dc_cycle_us or self.config.cycle_us) * 1000
            for s in self.config.slaves:
                b.configure_dc(s.position, cycle, self.config.dc_shift_us * 1000)
        b.request_state(AlState.SAFEOP, timeout=op_timeout)
        self.wait_op(op_timeout)
        self.started = True

    def wait_op(self, timeout: float) -> None:
        """``ecan_igh_wait_op_timeout``: every adapter slave in OP within ``timeout`` seconds."""
        for s in self.config.slaves:
            self.backend.request_state(AlState.OP, s.position, timeout=timeout)

    def all_op(self) -> bool:
        """Every adapter slave reports OP (15.5.2 step 8)."""
        return all(self.backend.state(s.position)[0] == AlState.OP for s in self.config.slaves)

    def stop(self) -> None:
        """Back to PREOP (safe state: the gateway stops sending) ; errors are not raised again."""
        try:
            self.backend.request_state(AlState.PREOP, timeout=2.0)
        except (ProtocolError, TimeoutError):
            pass

    # ------------------------------------------------------------------ process data
    def rxpdo(self, k: int) -> memoryview:
        """``ecan_igh_get_rxpdo_buffer``: the writable RxPDO bytes of adapter slave ``k``."""
        return self.backend.outputs(self.slave(k).position)

    def txpdo(self, k: int) -> bytes:
        """``ecan_igh_get_txpdo_buffer``: the TxPDO bytes of adapter slave ``k`` after the last cycle."""
        return self.backend.inputs(self.slave(k).position)

    def exchange(self) -> CycleStatus:
        """One process-data cycle; counts a working counter other than expected (domain incomplete)."""
        wkc, expected = self.backend.exchange()
        now = self.clock.now()
        self.master_period.mark(now)
        self.cycles += 1
        status = CycleStatus(wkc, expected, now)
        if not status.complete:
            self.wkc_errors += 1
        self.last = status
        return status

    @property
    def domain_complete(self) -> bool:
        """``ecan_igh_domain_is_complete`` for the last cycle (False before the first)."""
        return self.last is not None and self.last.complete

    def wait_period(self) -> None:
        """Wait until the next absolute cycle boundary (no drift, 13.9 'absolute time period')."""
        now = self.clock.now()
        if self._deadline is None or self._deadline < now - self.period:
            self._deadline = now
        self._deadline += self.period
        # wait(0) too when late: a clock nobody else runs (PysoemBackend's) runs its due timers in
        # wait(), e.g. the SDO client's timeouts
        self.clock.wait(max(0.0, self._deadline - now))
