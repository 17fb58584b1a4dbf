"""ECAN-Lite system and maintenance objects: 0x8000, 0x8020, 0x8030, 0xA000..0xA003, 0xB000, 0xF000.

The flash image (``flash.py``) and the FoE update (``ota.py``) are driven from here: per-channel
save/load/factory reset (0x800x:03), the device commands of 0xB000:04, the start-up load that
falls back to factory defaults and reports why in 0xB000:05. Access modes (0xB000:01..03) expire
on the injected clock.
"""

from __future__ import annotations

import enum
import zlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from gatewaylab.devices.ecanlite import flash as fl
from gatewaylab.devices.ecanlite.mcan.filters import FilterElement
from gatewaylab.devices.ecanlite.mcan.layout import ApplyStatus, ChannelSettings
from gatewaylab.devices.ecanlite.mcan.objects import (
    CHANNELS,
    CONFIG_BASE,
    CONFIG_PERSISTED,
    CONFIG_ROWS,
    EXT_LIST_MAX,
    POLICY_BASE,
    POLICY_PERSISTED,
    POLICY_ROWS,
    RX_CACHE_MAX,
    STD_LIST_MAX,
    TX_CACHE_MAX,
    Row,
    rows_object,
)
from gatewaylab.devices.ecanlite.mcan.registers import WRITE_WHITELIST
from gatewaylab.devices.ecanlite.model_port import ModelPort
from gatewaylab.devices.ecanlite.ota import OtaHandler, OtaStatus, Package
from gatewaylab.ethercat.description import ObjectDef
from gatewaylab.od import Access, DataType, Entry, ObjectDictionary, SdoAbort, SdoAbortCode

if TYPE_CHECKING:
    from gatewaylab.ethercat.foe import FoeHandler

U8, U16, U32 = DataType.UNSIGNED8, DataType.UNSIGNED16, DataType.UNSIGNED32
RO, RW, WO = Access.RO, Access.RW, Access.WO

SYSTEM_INDEX = 0x8000
GLOBAL_INDEX = 0x8020
TEST_INDEX = 0x8030
REGISTER_BASE = 0xA000
MAINTENANCE_INDEX = 0xB000
CAPABILITY_INDEX = 0xF000
#: 0x8030:01 value that unlocks the test controls ("ECAN").
TEST_KEY = 0x4543414E
#: 13.6 register service offset range.
REGISTER_RANGE = (0x0004, 0x0404)
#: Default engineering/factory access timeout, seconds (0xB000:03; 0 = no timeout).
ACCESS_TIMEOUT_S = 300

SYSTEM_ROWS: tuple[Row, ...] = (
    (1, "Reboot command", U8, 0, WO), (3, "CPU voltage", U16, 1275, RW), (4, "CPU clock hz", U32, 400_000_000, RO),
    (5, "BUS clock hz", U32, 200_000_000, RO), (6, "MCAN0 clock hz", U32, 80_000_000, RO),
    (7, "MCAN1 clock hz", U32, 80_000_000, RO), (8, "MCAN2 clock hz", U32, 80_000_000, RO),
    (9, "MCAN3 clock hz", U32, 80_000_000, RO), (10, "Config version", U32, 0, RW),
    (11, "Last apply result", U32, 0, RO), (12, "CAN pin rotation", U8, 0, RW),
    (13, "Active CAN pin rotation", U8, 0, RO), (14, "CAN pin rotation mask", U8, 0x0F, RO),
    (15, "CAN pin apply status", U8, 0, RO),
)
SYSTEM_PERSISTED = (3, 10, 12)
GLOBAL_ROWS: tuple[Row, ...] = (
    (1, "Control format", U16, 1, RO), (2, "Apply command", U8, 0, RW), (3, "Apply status", U8, 0, RO),
    (4, "Compat mode", U16, 3, RW), (5, "Runtime option flags", U32, 0, RW),
    (6, "Diagnostic option flags", U32, 0, RW), (7, "Max service budget us", U16, 1000, RW),
    (8, "Reserved0", U16, 0, RO), (9, "Reserved1", U32, 0, RO), (10, "Reserved2", U32, 0, RO),
)
GLOBAL_PERSISTED = (4, 5, 6, 7)
TEST_ROWS: tuple[Row, ...] = (
    (1, "Test enable key", U32, 0, RW), (2, "TxPDO bypass flags", U32, 0, RW), (3, "RxPDO bypass flags", U32, 0, RW),
    (4, "CRC test policy", U8, 0, RW), (5, "Payload only policy", U8, 0, RW),
    (6, "App link bypass policy", U8, 0, RW), (7, "ReservedPad", U8, 0, RO),
    (8, "Legal combination mask", U32, 0x1F, RO), (9, "Last reject reason", U32, 0, RO),
    (10, "Reserved0", U32, 0, RO),
)
REGISTER_ROWS: tuple[Row, ...] = (
    (1, "Offset", U32, 0x0004, RW), (2, "Command", U8, 0, RW), (3, "Status", U8, 0, RO),
    (4, "Write value", U32, 0, RW), (5, "Read value", U32, 0, RO), (6, "Timestamp low", U32, 0, RO),
    (7, "Timestamp high", U32, 0, RO),
)
MAINTENANCE_ROWS: tuple[Row, ...] = (
    (1, "Access mode request", U8, 0, RW), (2, "Access status", U8, 0, RO),
    (3, "Access timeout s", U16, ACCESS_TIMEOUT_S, RW), (4, "Maintenance command", U8, 0, WO),
    (5, "Maintenance status", U8, 0, RO), (6, "Legacy maintenance diag flags", U16, 0, RO),
    (7, "Active config CRC32", U32, 0, RO), (8, "Stored config CRC32", U32, 0, RO),
    (9, "FoE image size", U32, 0, RO), (10, "FoE image CRC32", U32, 0, RO), (11, "FoE status code", U32, 0, RO),
    (12, "Maintenance sequence", U32, 0, RO),
)
CAPABILITY_ROWS: tuple[Row, ...] = (
    (1, "Device type", U8, 0, RO), (2, "Channel count", U8, CHANNELS, RO), (3, "Capability version", U16, 1, RO),
    (4, "Hardware revision", U32, 0, RO), (5, "Firmware version major", U16, 0, RO),
    (6, "Firmware version minor", U16, 0, RO), (7, "Serial number low", U32, 0, RO),
    (8, "Serial number high", U32, 0, RO), (9, "PDO header version mask", U16, 0x0002, RO),
    (10, "PDO size multiplier min", U8, 1, RO), (11, "PDO size multiplier max", U8, 24, RO),
    (12, "Encapsulation profile mask", U32, 0x00000033, RO), (13, "Max PDO bytes", U16, 3072, RO),
    (14, "Max CAN channels", U8, CHANNELS, RO), (15, "PDO option flags mask", U8, 0x1F, RO),
    (16, "PDO feature flags", U32, 0x00001F3B, RO), (17, "PDO size unit bytes", U16, 128, RO),
    (18, "PDO fixed header bytes", U16, 24, RO), (19, "Device service flags", U32, 0x15, RO),
    (20, "Object extension set", U16, 1, RO), (21, "Data path extension set", U16, 1, RO),
    (22, "Diagnostic extension set", U16, 1, RO), (23, "Reserved capability pad", U16, 0, RO),
    (24, "Data path feature flags", U32, 0x1F, RO), (25, "Diagnostic feature flags", U32, 0x1F, RO),
    (26, "Runtime option flags mask", U32, 0, RO), (27, "Diagnostic option flags mask", U32, 0, RO),
    (28, "MCAN RX cache max depth", U16, RX_CACHE_MAX, RO), (29, "MCAN TX cache max depth", U16, TX_CACHE_MAX, RO),
    (30, "Max service budget us", U16, 1000, RO), (31, "Reserved capability0", U16, 0, RO),
    (32, "Reserved capability1", U32, 0, RO),
)


class AccessMode(enum.IntEnum):
    """0xB000:01/02 access modes (13.7)."""

    RUN = 0
    ENGINEERING = 1
    FACTORY = 2


class MaintenanceStatus(enum.IntEnum):
    """0xB000:05, in the order 13.7 lists them: OK/busy/denied/crc error/image invalid/flash error."""

    OK = 0
    BUSY = 1
    DENIED = 2
    CRC_ERROR = 3
    IMAGE_INVALID = 4
    FLASH_ERROR = 5


class RegisterStatus(enum.IntEnum):
    """0xA00x:03 (13.6)."""

    OK = 0
    OFFSET_INVALID = 1
    WRITE_DENIED = 2
    BUSY = 3
    ACCESS_DENIED = 4


class RejectReason(enum.IntEnum):
    """0x8030:09 last reject reason (gatewaylab's codes, docs/devices/ecanlite-mcan.md)."""

    NONE = 0
    KEY_REQUIRED = 1
    UNSUPPORTED_BITS = 2
    BAD_POLICY = 3
    APP_AND_FINE_BYPASS = 4
    BAD_KEY = 5


class DiagFlag(enum.IntFlag):
    """0xB000:06 legacy maintenance diag flags (13.7)."""

    SHADOW_FALLBACK = 1 << 0
    SHADOW_COPY_RETRY = 1 << 1
    SHADOW_SIZE_CHANGE = 1 << 2
    RXPDO_STAGE_DROP = 1 << 3
    TX_RING_DROP = 1 << 4
    TX_FIFO_FULL = 1 << 5
    SCHED_LATE_DROP = 1 << 6
    SCHED_QUEUE_FULL = 1 << 7
    SCHED_TX_FAIL = 1 << 8
    SCHED_TIMER_MISS = 1 << 9


#: 0x8030:02 TxPDO fine bypass bits 2..4, :03 RxPDO bits 2..5 (13.2.3).
TX_BYPASS_BITS = 0b11100
RX_BYPASS_BITS = 0b111100


@dataclass(frozen=True, slots=True)
class TestControls:
    """The 0x8030 test controls in force (all zero unless the key is set)."""

    tx_bypass: int = 0
    rx_bypass: int = 0
    crc_policy: int = 0
    payload_only: int = 0
    app_bypass: int = 0


def _size(rows: tuple[Row, ...]) -> dict[int, int]:
    return {r[0]: {U8: 1, U16: 2, U32: 4}[r[2]] for r in rows}


_SIZES: dict[int, dict[int, int]] = {SYSTEM_INDEX: _size(SYSTEM_ROWS), GLOBAL_INDEX: _size(GLOBAL_ROWS)}
for _k in range(CHANNELS):
    _SIZES[CONFIG_BASE + _k] = _size(CONFIG_ROWS)
    _SIZES[POLICY_BASE + _k] = _size(POLICY_ROWS)


def _record(index: int, sub: int, value: int) -> fl.Record:
    n = _SIZES[index][sub]
    return fl.Record(index, sub, (int(value) & ((1 << 8 * n) - 1)).to_bytes(n, "little"))


def _defaults(rows: tuple[Row, ...]) -> dict[int, int]:
    return {r[0]: r[3] for r in rows}


class SystemModel:
    """0x8000, 0x8020, 0x8030, 0xA000..0xA003, 0xB000, 0xF000 of one device, flash and FoE (model: ModelPort)."""

    def __init__(self, model: ModelPort, *, serial: int = 0, hardware_revision: int = 0) -> None:
        self.model = model
        self.clock = model.clock
        self.serial = serial
        self.hardware_revision = hardware_revision
        self.system = _defaults(SYSTEM_ROWS)
        self.global_control = _defaults(GLOBAL_ROWS)
        self.test = TestControls()
        self.reject_reason = RejectReason.NONE
        self.access = AccessMode.RUN
        self._access_since = 0.0
        self.access_timeout = ACCESS_TIMEOUT_S
        self.status = MaintenanceStatus.OK
        self.sequence = 0
        self.diag_flags = DiagFlag(0)
        self.stored_crc = 0
        self.ota = OtaStatus()
        #: Called for 0x8000:01 = 1 and 0xB000:04 bit 6 (the device reboots); None = model.reset().
        self.on_reboot: Callable[[], None] | None = None
        self.od: ObjectDictionary | None = None

    # -- objects ---------------------------------------------------------------------------------
    def object_defs(self) -> list[ObjectDef]:
        """0x8000, 0x8020, 0x8030, 0xA000..0xA003, 0xB000, 0xF000."""
        out = [rows_object(SYSTEM_INDEX, "System Config", SYSTEM_ROWS),
               rows_object(GLOBAL_INDEX, "Data Path Global Control", GLOBAL_ROWS),
               rows_object(TEST_INDEX, "PDO Diagnostic Test Control", TEST_ROWS),
               rows_object(MAINTENANCE_INDEX, "Device Maintenance", MAINTENANCE_ROWS),
               rows_object(CAPABILITY_INDEX, "Device Objects", CAPABILITY_ROWS)]
        out += [rows_object(REGISTER_BASE + k, f"MCAN{k} Register Service", REGISTER_ROWS) for k in range(CHANNELS)]
        return out

    def capability(self) -> dict[int, int]:
        """0xF000 values: the 13.8 defaults plus version, serial and hardware revision."""
        v = self.model.version
        values = _defaults(CAPABILITY_ROWS)
        values.update({4: self.hardware_revision, 5: v.major_minor, 6: v.build,
                       7: self.serial & 0xFFFFFFFF, 8: (self.serial >> 32) & 0xFFFFFFFF})
        return values

    def install(self, slave: Any, od: ObjectDictionary, *, hook: bool = True) -> None:
        """Values and (with ``hook``) hooks of the system objects."""
        self.od = od
        put = self._put
        put(SYSTEM_INDEX, self.system)
        put(GLOBAL_INDEX, self.global_control)
        put(CAPABILITY_INDEX, self.capability())
        put(TEST_INDEX, {8: 0x1F, 9: int(self.reject_reason)})
        self._publish_maintenance()
        if 0x100A in od:
            od.put(0x100A, 0, self.model.version_string)
        if not hook:
            return
        od.add_validator(SYSTEM_INDEX, self._system_validator)
        od.add_reaction(SYSTEM_INDEX, self._system_reaction)
        od.add_reaction(GLOBAL_INDEX, self._global_reaction)
        od.add_validator(TEST_INDEX, self._test_validator)
        od.add_reaction(TEST_INDEX, self._test_reaction)
        od.add_validator(MAINTENANCE_INDEX, self._maintenance_validator)
        od.add_reaction(MAINTENANCE_INDEX, self._maintenance_reaction)
        od.on_read(MAINTENANCE_INDEX, self._maintenance_read)
        for k in range(CHANNELS):
            od.add_validator(REGISTER_BASE + k, self._register_validator)
            od.add_reaction(REGISTER_BASE + k, self._register_reaction)

    def _put(self, index: int, values: Mapping[int, int]) -> None:
        od = self.od
        if od is not None:
            od.put_many([(index, s) for s in values], [int(v) & 0xFFFFFFFF for v in values.values()])

    # -- start-up and flash ----------------------------------------------------------------------
    def _read_image(self) -> list[fl.Record]:
        """The stored records; ImageError when missing (image invalid) or unusable."""
        try:
            raw = self.model.flash.read()
        except OSError as exc:
            raise fl.ImageError(f"flash unreadable: {exc}", fl.ImageStatus.IMAGE_INVALID) from None
        if raw is None:
            raise fl.ImageError("no configuration image", fl.ImageStatus.IMAGE_INVALID)
        self.stored_crc = fl.image_crc(raw)
        return fl.decode_image(raw)

    def power_on(self) -> None:
        """Load the flash image; a missing or corrupted one means factory defaults, and
        0xB000:05 says why (3 crc error, 4 image invalid)."""
        try:
            records = self._read_image()
            self.status = MaintenanceStatus.OK
        except fl.ImageError as exc:
            records = []
            self.status = MaintenanceStatus(int(exc.status))
            self.stored_crc = 0 if exc.status is fl.ImageStatus.IMAGE_INVALID else self.stored_crc
        self._load_system(records)
        for k in range(CHANNELS):
            self._load_channel(k, records, fallback=True)
        self._publish_maintenance()

    def _load_system(self, records: list[fl.Record]) -> None:
        sysv = _defaults(SYSTEM_ROWS)
        glob = _defaults(GLOBAL_ROWS)
        for r in records:
            if r.index == SYSTEM_INDEX and r.subindex in SYSTEM_PERSISTED:
                sysv[r.subindex] = int.from_bytes(r.value, "little")
            elif r.index == GLOBAL_INDEX and r.subindex in GLOBAL_PERSISTED:
                glob[r.subindex] = int.from_bytes(r.value, "little")
        if sysv[12] > 3:
            sysv[12] = 0
        sysv[13] = sysv[12]
        self.model.rotate(sysv[13])
        self.system = sysv
        self.global_control = glob
        self._put(SYSTEM_INDEX, sysv)
        self._put(GLOBAL_INDEX, glob)

    def _load_channel(self, k: int, records: list[fl.Record], *, fallback: bool) -> ApplyStatus | None:
        """Channel ``k``'s settings from ``records``; None when the image has none for it."""
        model = self.model
        cfg: dict[int, int] = {}
        pol: dict[int, int] = {}
        std = [FilterElement()] * STD_LIST_MAX
        ext = [FilterElement()] * EXT_LIST_MAX
        found = False
        try:
            for r in records:
                if r.index == CONFIG_BASE + k:
                    found = True
                    if fl.STD_FILTER_SUB <= r.subindex < fl.STD_FILTER_SUB + STD_LIST_MAX:
                        std[r.subindex - fl.STD_FILTER_SUB] = FilterElement(*fl.unpack_filter(r.value))
                    elif fl.EXT_FILTER_SUB <= r.subindex < fl.EXT_FILTER_SUB + EXT_LIST_MAX:
                        ext[r.subindex - fl.EXT_FILTER_SUB] = FilterElement(*fl.unpack_filter(r.value))
                    elif r.subindex in CONFIG_PERSISTED:
                        cfg[r.subindex] = int.from_bytes(r.value, "little")
                elif r.index == POLICY_BASE + k and r.subindex in POLICY_PERSISTED:
                    found = True
                    pol[r.subindex] = int.from_bytes(r.value, "little")
        except fl.ImageError:
            found = False
        if not found and not fallback:
            return None
        status = model.load_channel_settings(k, cfg, std, ext)
        if model.load_policy_values(k, pol) != 0:
            model.load_policy_values(k, {})
        if status != ApplyStatus.OK and fallback:
            model.load_channel_settings(k, {}, (), ())
        return status

    def records(self, channels: range | None = None, *, system: bool = True) -> list[fl.Record]:
        """The records of the requested configuration (what a save writes)."""
        model = self.model
        out: list[fl.Record] = []
        if system:
            out += [_record(SYSTEM_INDEX, s, self._value(SYSTEM_INDEX, s, self.system)) for s in SYSTEM_PERSISTED]
            out += [_record(GLOBAL_INDEX, s, self._value(GLOBAL_INDEX, s, self.global_control))
                    for s in GLOBAL_PERSISTED]
        for k in channels if channels is not None else range(CHANNELS):
            cfg = model.config_values(k)
            out += [_record(CONFIG_BASE + k, s, cfg[s]) for s in CONFIG_PERSISTED]
            ch = model.channels[k]
            for base, lst in ((fl.STD_FILTER_SUB, ch.std_filters), (fl.EXT_FILTER_SUB, ch.ext_filters)):
                for i, f in enumerate(lst):
                    if f != FilterElement():
                        out.append(fl.Record(CONFIG_BASE + k, base + i,
                                             fl.pack_filter(f.type, f.action, f.sync, f.id1, f.id2)))
            pol = model.policy_values(k)
            out += [_record(POLICY_BASE + k, s, pol[s]) for s in POLICY_PERSISTED]
        return out

    def _value(self, index: int, sub: int, fallback: Mapping[int, int]) -> int:
        od = self.od
        if od is not None:
            return int(od.values[(index, sub)])
        return int(fallback[sub])

    def active_crc(self) -> int:
        """0xB000:07: CRC32 of the payload a save would write now."""
        return zlib.crc32(fl.encode_payload(self.records()))

    def _write(self, records: list[fl.Record]) -> bool:
        image = fl.encode_image(records)
        try:
            self.model.flash.write(image)
        except OSError:
            return False
        self.stored_crc = fl.image_crc(image)
        return True

    def _stored_records(self) -> list[fl.Record]:
        try:
            return self._read_image()
        except fl.ImageError:
            return []

    def channel_flash(self, k: int, bits: int) -> ApplyStatus:
        """0x800x:03: bit0 save, bit1 load, bit2 factory reset (in that order)."""
        if bits & ~0x07:
            return ApplyStatus.FAIL
        status = ApplyStatus.OK
        if bits & 1:
            keep = [r for r in self._stored_records() if r.index not in (CONFIG_BASE + k, POLICY_BASE + k)]
            if not self._write(keep + self.records(range(k, k + 1), system=False)):
                status = ApplyStatus.FAIL
        if bits & 2:
            try:
                records = self._read_image()
            except fl.ImageError:
                status = ApplyStatus.FAIL
            else:
                loaded = self._load_channel(k, records, fallback=False)
                status = ApplyStatus.FAIL if loaded is None else loaded
        if bits & 4:
            status = self.model.load_channel_settings(k, {}, (), ())
            self.model.load_policy_values(k, {})
        self._publish_maintenance()
        return status

    # -- OTA -------------------------------------------------------------------------------------
    def ota_handler(self, on_accepted: Callable[[], None]) -> FoeHandler:
        """The ``ecan_lite_app`` FoE handler."""
        def accepted() -> None:
            self._publish_maintenance()
            on_accepted()

        def install(package: Package, data: bytes) -> None:
            self.model.flash.write_app(data)
            self._install_package(package)

        handler = OtaHandler(install, accepted, self.ota)
        return _PublishingHandler(handler, self._publish_maintenance)

    def _install_package(self, package: Package) -> None:
        self.model.version = package.version
        self._put(CAPABILITY_INDEX, self.capability())
        od = self.od
        if od is not None and 0x100A in od:
            od.put(0x100A, 0, self.model.version_string)

    # -- access modes ----------------------------------------------------------------------------
    def access_mode(self) -> AccessMode:
        """The access status now (engineering/factory fall back to run after the timeout)."""
        if (self.access is not AccessMode.RUN and self.access_timeout
                and self.clock.now() - self._access_since >= self.access_timeout):
            self.access = AccessMode.RUN
        return self.access

    # -- hooks -----------------------------------------------------------------------------------
    def _system_validator(self, entry: Entry, value: Any) -> None:
        if entry.subindex == 12 and int(value) > 0xFF:
            raise SdoAbort(SdoAbortCode.VALUE_RANGE_EXCEEDED, "pin rotation")

    def _system_reaction(self, entry: Entry, value: Any) -> None:
        sub = entry.subindex
        assert self.od is not None
        if sub == 1:
            self.od.put(SYSTEM_INDEX, 1, 0)
            if int(value) == 1:
                self.clock.call_soon(self._reboot)
        elif sub == 12:
            rotation = int(value)
            ok = rotation <= 3 and bool(self.system[14] & (1 << rotation))
            if ok:
                self.system[13] = rotation
                self.model.rotate(rotation)
            self.system[12] = rotation
            self.system[15] = 0 if ok else 1
            self.system[11] = self.system[15]
            self._put(SYSTEM_INDEX, {13: self.system[13], 15: self.system[15], 11: self.system[11]})
        elif sub in (3, 10):
            self.system[sub] = int(value)

    def _reboot(self) -> None:
        if self.on_reboot is not None:
            self.on_reboot()
        else:
            self.model.reset()

    def _global_reaction(self, entry: Entry, value: Any) -> None:
        assert self.od is not None
        if entry.subindex != 2:
            return
        self.od.put(GLOBAL_INDEX, 2, 0)
        if int(value) == 0:
            return
        v = {s: int(self.od.values[(GLOBAL_INDEX, s)]) for s in GLOBAL_PERSISTED}
        ok = int(value) == 1 and v[5] == 0 and v[6] == 0 and v[7] <= 1000
        if ok:
            self.global_control.update(v)
        self.od.put(GLOBAL_INDEX, 3, 0 if ok else 1)

    def _reject(self, reason: RejectReason, code: SdoAbortCode, text: str) -> SdoAbort:
        self.reject_reason = reason
        self._put(TEST_INDEX, {9: int(reason)})
        return SdoAbort(code, text)

    def _test_validator(self, entry: Entry, value: Any) -> None:
        assert self.od is not None
        sub, v = entry.subindex, int(value)
        if sub == 1:
            if v not in (0, TEST_KEY):
                raise self._reject(RejectReason.BAD_KEY, SdoAbortCode.VALUE_RANGE_EXCEEDED, "wrong test key")
            return
        if int(self.od.values[(TEST_INDEX, 1)]) != TEST_KEY:
            raise self._reject(RejectReason.KEY_REQUIRED, SdoAbortCode.DATA_CANNOT_BE_STORED_DEVICE_STATE,
                               "write 0x4543414E to 0x8030:01 first")
        if (sub == 2 and v & ~TX_BYPASS_BITS) or (sub == 3 and v & ~RX_BYPASS_BITS):
            raise self._reject(RejectReason.UNSUPPORTED_BITS, SdoAbortCode.VALUE_RANGE_EXCEEDED,
                               "unsupported bypass bits")
        if (sub == 4 and v > 2) or (sub in (5, 6) and v > 3):
            raise self._reject(RejectReason.BAD_POLICY, SdoAbortCode.VALUE_RANGE_EXCEEDED, "policy value")
        t = self._test_with(sub, v)
        if (t.app_bypass & 1 and t.tx_bypass) or (t.app_bypass & 2 and t.rx_bypass):
            raise self._reject(RejectReason.APP_AND_FINE_BYPASS, SdoAbortCode.GENERAL_PARAMETER_INCOMPATIBILITY,
                               "application bypass and fine bypass in the same direction")

    def _test_with(self, sub: int, v: int) -> TestControls:
        t = self.test
        fields = {2: "tx_bypass", 3: "rx_bypass", 4: "crc_policy", 5: "payload_only", 6: "app_bypass"}
        name = fields.get(sub)
        if name is None:
            return t
        return TestControls(**{**{f: getattr(t, f) for f in fields.values()}, name: v})

    def _test_reaction(self, entry: Entry, value: Any) -> None:
        sub = entry.subindex
        if sub == 1:
            if int(value) == 0:
                self.test = TestControls()
                self._put(TEST_INDEX, {2: 0, 3: 0, 4: 0, 5: 0, 6: 0})
        else:
            self.test = self._test_with(sub, int(value))
            self.reject_reason = RejectReason.NONE
            self._put(TEST_INDEX, {9: 0})
        for ch in self.model.channels:
            ch.bypass_read = bool(self.test.tx_bypass & 0x04)
            ch.bypass_write = bool(self.test.rx_bypass & 0x30)

    def _register_validator(self, entry: Entry, value: Any) -> None:
        if entry.subindex == 2 and int(value) > 2:
            raise SdoAbort(SdoAbortCode.VALUE_RANGE_EXCEEDED, "register command is 0, 1 or 2")

    def _register_reaction(self, entry: Entry, value: Any) -> None:
        if entry.subindex != 2 or int(value) == 0:
            return
        od = self.od
        assert od is not None
        index = entry.index
        ch = self.model.channels[index - REGISTER_BASE]
        offset = int(od.values[(index, 1)])
        out: dict[int, int] = {2: 0}
        if not (REGISTER_RANGE[0] <= offset <= REGISTER_RANGE[1]) or offset % 4:
            status = RegisterStatus.OFFSET_INVALID
        elif int(value) == 1:
            out[5] = ch.register(offset)
            status = RegisterStatus.OK
        elif offset not in WRITE_WHITELIST:
            status = RegisterStatus.WRITE_DENIED
        elif self.access_mode() is AccessMode.RUN:
            status = RegisterStatus.ACCESS_DENIED
        elif ch.write_register(offset, int(od.values[(index, 4)])):
            status = RegisterStatus.OK
        else:
            status = RegisterStatus.WRITE_DENIED   # a value the channel cannot run (docs/decisions.md)
        ns = int(self.clock.now() * 1e9) & 0xFFFFFFFFFFFFFFFF
        out.update({3: int(status), 6: ns & 0xFFFFFFFF, 7: ns >> 32})
        self._put(index, out)

    def _maintenance_validator(self, entry: Entry, value: Any) -> None:
        sub, v = entry.subindex, int(value)
        if sub == 1 and v > 2:
            raise SdoAbort(SdoAbortCode.VALUE_RANGE_EXCEEDED, "access mode is 0, 1 or 2")
        if sub == 4 and (v & 0x80 or (v & 0x60 and v not in (0x20, 0x40))):
            raise SdoAbort(SdoAbortCode.VALUE_RANGE_EXCEEDED, "bits 5 and 6 are standalone commands")

    def _maintenance_reaction(self, entry: Entry, value: Any) -> None:
        sub, v = entry.subindex, int(value)
        if sub == 1:
            self.access = AccessMode(v)
            self._access_since = self.clock.now()
        elif sub == 3:
            self.access_timeout = v
        elif sub == 4:
            assert self.od is not None
            self.od.put(MAINTENANCE_INDEX, 4, 0)
            if v:
                self.status = self.command(v)
                self.sequence = (self.sequence + 1) & 0xFFFFFFFF
        self._publish_maintenance()

    def command(self, bits: int) -> MaintenanceStatus:
        """0xB000:04 (13.7): bit0 save, bit1 load, bit2 factory reset, bit3 FoE validate,
        bit4 FoE activate; bit5 clear diagnostics and bit6 EEPROM rebuild + reboot alone.
        Factory reset, FoE activate and EEPROM rebuild need engineering or factory access."""
        mode = self.access_mode()
        if bits & 0b1010100 and mode is AccessMode.RUN:
            return MaintenanceStatus.DENIED
        if bits == 0x20:
            for ch in self.model.channels:
                ch.clear_diagnostics()
            self.diag_flags = DiagFlag(0)
            return MaintenanceStatus.OK
        if bits == 0x40:
            self.clock.call_soon(self._reboot)
            return MaintenanceStatus.OK
        status = MaintenanceStatus.OK
        if bits & 1 and not self._write(self.records()):
            status = MaintenanceStatus.FLASH_ERROR
        if bits & 2:
            try:
                records = self._read_image()
            except fl.ImageError as exc:
                status = MaintenanceStatus(int(exc.status))
            else:
                self._load_system(records)
                for k in range(CHANNELS):
                    self._load_channel(k, records, fallback=False)
        if bits & 4:
            self._load_system([])
            for k in range(CHANNELS):
                self.model.load_channel_settings(k, {}, (), ())
                self.model.load_policy_values(k, {})
        if bits & 0x18:
            from gatewaylab.devices.ecanlite.ota import OtaError, unpack
            try:
                package = unpack(self.ota.last_image)
            except OtaError:
                status = MaintenanceStatus.IMAGE_INVALID
            else:
                if bits & 0x10:
                    try:
                        self.model.flash.write_app(self.ota.last_image)
                    except OSError:
                        return MaintenanceStatus.FLASH_ERROR
                    self._install_package(package)
                    self.clock.call_soon(self._reboot)
        return status

    def _maintenance_read(self, index: int, subindex: int) -> None:
        self._publish_maintenance()

    def _publish_maintenance(self) -> None:
        if self.od is None:
            return
        flags = self.diag_flags
        for ch in self.model.channels:
            if ch.counters.tx_fifo_full:
                flags |= DiagFlag.TX_FIFO_FULL
            if ch.counters.tx_stale_dropped:
                flags |= DiagFlag.TX_RING_DROP
        mode = int(self.access_mode())
        self._put(MAINTENANCE_INDEX, {
            1: mode, 2: mode, 3: self.access_timeout, 5: int(self.status), 6: int(flags),
            7: self.active_crc(), 8: self.stored_crc, 9: self.ota.image_size, 10: self.ota.image_crc32,
            11: self.ota.status_code, 12: self.sequence})


class _PublishingHandler:
    """The OTA handler, refreshing 0xB000:09..11 after every write (good or bad)."""

    def __init__(self, inner: OtaHandler, publish: Callable[[], None]) -> None:
        self.inner = inner
        self._publish = publish

    def foe_read(self, name: str, password: int) -> bytes:
        """Firmware cannot be read back."""
        return self.inner.foe_read(name, password)

    def foe_write(self, name: str, password: int, data: bytes) -> None:
        """Verify and install; 0xB000 shows the outcome."""
        try:
            self.inner.foe_write(name, password, data)
        finally:
            self._publish()


__all__ = ["AccessMode", "ChannelSettings", "DiagFlag", "MaintenanceStatus", "RegisterStatus", "RejectReason",
           "SystemModel", "TestControls"]
