"""A CoE CiA 402 servo drive as an EtherCAT slave (ETG.6010), 1..4 axes.

Each axis is the CANopen drive of ``canopen/drive.py`` -- the same CiA 402 state machine, modes,
0x603F error codes and motion plant -- hosted by an EtherCAT slave instead of a CAN node:

* **One dictionary.** The slave's dictionary gets the drive's own rows from
  :func:`~gatewaylab.devices.canopen_drive.device.add_profile_objects` (``DeviceDescription.extend_od``), and
  axis 0's :class:`~gatewaylab.devices.canopen_drive.device.Drive` runs on that very dictionary: a CoE upload of
  0x6064 reads the value the control loop published. Axes 1..3 (ETG.6010 multi-axis) have their
  rows at +0x800 per axis, generated from the same rows; each of them runs on its own
  dictionary, which a :class:`_AxisMirror` keeps equal to the slave's rows both ways.
* **PDOs** (ETG.6010 default assignment): RxPDO 0x1600 + 0x10 n (0x6040, 0x607A, 0x60FF, 0x6071,
  0x6060), TxPDO 0x1A00 + 0x10 n (0x6041, 0x6064, 0x606C, 0x6077, 0x6061, 0x603F); fixed CSP
  (0x1601 / 0x1A01) and CSV (0x1602 / 0x1A02) alternatives. Mapping and assignment are written
  in PREOP (the core's sub-index 0 rule); an object mapped twice refuses SAFEOP with 0x0025 /
  0x0024 (invalid output / input mapping).
* **Synchronisation** (ETG.1020, 0x1C32 / 0x1C33): free run (the drive's own 1 ms timer),
  SM-synchronous (a control period per outputs event, right after the frame; a period still
  pending when the next frame comes runs then and counts in 0x1C32:0C) and DC SYNC0 (a control period at each
  SYNC0 + 0x1C32:03 shift, sampling the targets the dictionary holds then; pulses the ESC
  merged while the emulator was busy count as that many periods). The mode is what the
  master wrote to 0x1C32:01, else DC when it activated SYNC0 (0x0981), else SM-synchronous.
  In DC mode a SYNC0 without outputs since the previous one counts in 0x1C32:0B "SM event
  missed"; the sync error counter (+3 per miss, -1 per good cycle) above 0x10F1:02 sets
  0x1C32:20 and drops the slave to SAFEOP with AL status 0x001A "synchronization error".
* **Emergencies**: a drive fault (following error 0x8611, over-current 0x2310 when the motor
  torque stays at 0x6072 longer than 0x2010 ms) writes 0x603F and sends a CoE emergency (error
  code, error register 0x1001, 5 data bytes: the axis number); fault reset sends code 0x0000.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from functools import partial
from typing import Any

from gatewaylab.canopen.cia402 import PdsState
from gatewaylab.canopen.emcy import ERR_CURRENT, ERR_GENERIC
from gatewaylab.canopen.nmt import NmtState
from gatewaylab.common.clock import Clock, PeriodicTimer
from gatewaylab.common.errors import ConfigError
from gatewaylab.devices.canopen_drive.device import Drive
from gatewaylab.devices.canopen_drive.objects import DEVICE_TYPE, add_profile_objects
from gatewaylab.devices.canopen_drive.plant import AxisParams
from gatewaylab.devices.ethercat_io.device import VENDOR_ID
from gatewaylab.ethercat.description import DeviceDescription, Pdo, PdoEntry
from gatewaylab.ethercat.errors import AlStatusCode
from gatewaylab.ethercat.esc import AlState
from gatewaylab.ethercat.slave import Slave, SlaveApplication
from gatewaylab.od import Access, DataType, Entry, ObjectCode, ObjectDictionary, SdoAbort
from gatewaylab.od.dictionary import ReadHook, Validator, WriteHook

__all__ = ["AXIS_OFFSET", "PRODUCT_CODE", "DriveApplication", "EthercatDrive", "create_drive_slave",
           "drive_description"]

#: Product code of the emulated EtherCAT drive (vendor 'GWLB', see docs/decisions.md).
PRODUCT_CODE = 0x00020402
#: ETG.6010 multi-axis: the objects of axis n are at index + 0x800 n.
AXIS_OFFSET = 0x800
#: PDO mapping objects of axis n: 0x1600 + 0x10 n / 0x1A00 + 0x10 n (and +1, +2 alternatives).
PDO_STRIDE = 0x10
MAX_AXES = 4
#: Over-current supervision: torque at the limit longer than this (ms, per axis 0x2010 + 0x800 n).
OVERCURRENT_TIME_INDEX = 0x2010
ERROR_OVERCURRENT = 0x2310      # CiA 402 / CiA 301 "continuous over current"
#: ETG.1020 0x1C32:01 sync modes.
FREE_RUN, SM_SYNC, DC_SYNC0 = 0, 1, 2
#: 0x1C33:01 "synchronous with SM2 event" (ETG.1020).
SM2_EVENT = 0x22
MIN_CYCLE_NS = 250_000
DEFAULT_SYNC_ERROR_LIMIT = 4

_U8, _U16, _U32 = DataType.UNSIGNED8, DataType.UNSIGNED16, DataType.UNSIGNED32
_I8, _I16, _I32 = DataType.INTEGER8, DataType.INTEGER16, DataType.INTEGER32

#: (index, sub, bits, name, type) of the default and alternative PDOs of one axis (axis 0 indexes).
_RX_DEFAULT = ((0x6040, 16, "Controlword", _U16), (0x607A, 32, "Target position", _I32),
               (0x60FF, 32, "Target velocity", _I32), (0x6071, 16, "Target torque", _I16),
               (0x6060, 8, "Modes of operation", _I8))
_TX_DEFAULT = ((0x6041, 16, "Statusword", _U16), (0x6064, 32, "Position actual value", _I32),
               (0x606C, 32, "Velocity actual value", _I32), (0x6077, 16, "Torque actual value", _I16),
               (0x6061, 8, "Modes of operation display", _I8), (0x603F, 16, "Error code", _U16))
_RX_CSP = _RX_DEFAULT[:2]
_RX_CSV = (_RX_DEFAULT[0], _RX_DEFAULT[2])
_TX_CSP = _TX_DEFAULT[:2]
_TX_CSV = _TX_DEFAULT[:3]


def _pdo(index: int, name: str, rows: tuple[tuple[int, int, str, DataType], ...], off: int, *,
         fixed: bool = False, exclude: tuple[int, ...] = ()) -> Pdo:
    return Pdo(index, name, tuple(PdoEntry(i + off, 0, bits, n, t) for i, bits, n, t in rows),
               fixed=fixed, exclude=exclude)


def _axis_pdos(n: int) -> tuple[list[Pdo], list[Pdo]]:
    off, base = AXIS_OFFSET * n, PDO_STRIDE * n
    label = f" axis {n + 1}" if n else ""
    rx0, tx0 = 0x1600 + base, 0x1A00 + base
    rx = [_pdo(rx0, f"RxPDO{label}", _RX_DEFAULT, off, exclude=(rx0 + 1, rx0 + 2)),
          _pdo(rx0 + 1, f"RxPDO CSP{label}", _RX_CSP, off, fixed=True, exclude=(rx0, rx0 + 2)),
          _pdo(rx0 + 2, f"RxPDO CSV{label}", _RX_CSV, off, fixed=True, exclude=(rx0, rx0 + 1))]
    tx = [_pdo(tx0, f"TxPDO{label}", _TX_DEFAULT, off, exclude=(tx0 + 1, tx0 + 2)),
          _pdo(tx0 + 1, f"TxPDO CSP{label}", _TX_CSP, off, fixed=True, exclude=(tx0, tx0 + 2)),
          _pdo(tx0 + 2, f"TxPDO CSV{label}", _TX_CSV, off, fixed=True, exclude=(tx0, tx0 + 1))]
    return rx, tx


def _copy_rows(src: ObjectDictionary, dst: ObjectDictionary, off: int) -> None:
    """The rows of ``src`` into ``dst`` at index + ``off`` (ETG.6010 axis offset): same types,
    access, limits, defaults and PDO flags -- the rows themselves, not a second table of them."""
    for obj in src:
        index = obj.index + off
        if obj.object_code is ObjectCode.VAR:
            e = obj.entries[0]
            dst.add_variable(index, obj.name, e.data_type, e.access, e.default, pdo_mappable=e.pdo_mappable,
                             low=e.low, high=e.high, preop_only=e.preop_only)
            continue
        dst.add_record(index, obj.name, obj.object_code)
        for sub, e in sorted(obj.entries.items()):
            if sub:
                dst.add_sub(index, sub, e.name, e.data_type, e.access, e.default, pdo_mappable=e.pdo_mappable,
                            low=e.low, high=e.high, preop_only=e.preop_only)


def axis_rows(params: AxisParams | None = None) -> ObjectDictionary:
    """One axis's own dictionary: the drive's rows and its over-current time."""
    od = ObjectDictionary()
    add_profile_objects(od, params)
    od.add_variable(OVERCURRENT_TIME_INDEX, "Over-current time", _U16, Access.RW, 500)
    return od


def _extend_od(axes: int, params: AxisParams | None, od: ObjectDictionary) -> None:
    """The drive's rows (axis 0 at their own index, axis n at + 0x800 n), the error register, the
    error settings 0x10F1 and the ETG.1020 sync objects as a drive writes them."""
    add_profile_objects(od, params)
    od.add_variable(OVERCURRENT_TIME_INDEX, "Over-current time", _U16, Access.RW, 500)
    if axes > 1:
        template = axis_rows(params)
        for n in range(1, axes):
            _copy_rows(template, od, AXIS_OFFSET * n)
    od.add_variable(0x1001, "Error register", _U8, Access.RO, 0)
    od.add_record(0x10F1, "Error settings")
    od.add_sub(0x10F1, 1, "Local error reaction", _U32, Access.RW, 1)
    od.add_sub(0x10F1, 2, "Sync error counter limit", _U16, Access.RW, DEFAULT_SYNC_ERROR_LIMIT)
    for index in (0x1C32, 0x1C33):
        for sub in (2, 3):   # cycle time and shift time: written by masters that configure them
            od.replace_entry(replace(od.entry(index, sub), access=Access.RW, preop_only=True))
        od.put(index, 5, MIN_CYCLE_NS)
        od.put(index, 6, 50_000)


def drive_description(name: str = "GL-Drive CiA402", serial: int = 0, axes: int = 1,
                      params: AxisParams | None = None) -> DeviceDescription:
    """The EtherCAT drive: identity, per-axis PDOs, DC op modes (Free Run / SM / DC SYNC0)."""
    if not 1 <= axes <= MAX_AXES:
        raise ConfigError(f"ethercat_drive axes = {axes}: 1..{MAX_AXES}")
    rx: list[Pdo] = []
    tx: list[Pdo] = []
    for n in range(axes):
        r, t = _axis_pdos(n)
        rx += r
        tx += t
    return DeviceDescription(
        name=name, vendor_id=VENDOR_ID, product_code=PRODUCT_CODE, revision=axes, serial=serial,
        order_code=f"GL-DRV-402-{axes}", group="gatewaylab drives", device_type=DEVICE_TYPE,
        outputs_start=0x1100, inputs_start=0x1400, rx_pdos=tuple(rx), tx_pdos=tuple(tx),
        rx_assign=tuple(0x1600 + PDO_STRIDE * n for n in range(axes)),
        tx_assign=tuple(0x1A00 + PDO_STRIDE * n for n in range(axes)),
        dc_op_modes=(("FreeRun", "Free Run", 0), ("SM", "SM-Synchron", 0), ("DC", "DC-Synchron", 0x300)),
        extend_od=partial(_extend_od, axes, params))


class _ErrorRegister:
    """0x1001 of the device: the OR of every axis's active errors (+ generic while any is active)."""

    def __init__(self, od: ObjectDictionary) -> None:
        self.od = od
        self.axes: list[CoeEmergency] = []

    def update(self) -> int:
        reg = 0
        for axis in self.axes:
            for bits in axis.active.values():
                reg |= bits
        if reg:
            reg |= ERR_GENERIC
        self.od.put(0x1001, 0, reg)
        return reg


class CoeEmergency:
    """What the drive uses of the CANopen EMCY producer, sent as CoE emergencies (ETG.1000.6)."""

    def __init__(self, slave: Slave, axis: int, register: _ErrorRegister) -> None:
        self.slave = slave
        self.axis = axis
        self.register = register
        #: Active errors: code -> error register bits.
        self.active: dict[int, int] = {}
        self.sent: list[int] = []
        register.axes.append(self)

    def raise_error(self, code: int, register_bits: int = ERR_GENERIC, info: bytes = b"") -> None:
        """A new error: 0x1001 and one CoE emergency (once per error event, as on CANopen)."""
        if code in self.active:
            return
        self.active[code] = register_bits
        self._send(code, info)

    def clear_error(self, code: int) -> None:
        """The error went away (fault reset): emergency 'error reset / no error' (0x0000)."""
        if self.active.pop(code, None) is not None:
            self._send(0x0000, b"")

    def _send(self, code: int, info: bytes) -> None:
        reg = self.register.update()
        self.sent.append(code)
        data = info[:5] if info else bytes([self.axis + 1])
        self.slave.emergency(code, reg, data)


class CoeHost:
    """What the drive uses of a CANopen Node (Drive(host=...): a DriveHost) on an EtherCAT slave: the typed
    dictionary access, the CoE emergency producer and an NMT-like state that follows the EtherCAT
    state (OP = operational: statusword bit 9 'remote')."""

    def __init__(self, od: ObjectDictionary, emcy: CoeEmergency) -> None:
        self.od = od
        self.emcy = emcy
        self.nmt_state = NmtState.PRE_OPERATIONAL
        self.running = True
        self._nmt_hooks: list[Callable[[NmtState, NmtState], None]] = []

    def set(self, index: int, subindex: int, value: Any) -> None:
        """The drive's own write (event-driven process data sees the change)."""
        self.od.put(index, subindex, value)

    def get(self, index: int, subindex: int = 0) -> Any:
        """The typed value."""
        return self.od.get(index, subindex)

    def on_write(self, where: int | range, hook: WriteHook) -> None:
        """Write hooks on the axis's dictionary (CoE downloads and applied outputs)."""
        self.od.on_write(where, hook)

    def on_read(self, where: int | range, hook: ReadHook) -> None:
        """Read hooks on the axis's dictionary."""
        self.od.on_read(where, hook)

    def add_validator(self, where: int | range, validator: Validator) -> None:
        """Validators on the axis's dictionary."""
        self.od.add_validator(where, validator)

    def on_nmt_change(self, callback: Callable[[NmtState, NmtState], None]) -> None:
        """Called when the EtherCAT state enters or leaves OP."""
        self._nmt_hooks.append(callback)

    def on_reset(self, callback: Callable[[bool], None]) -> None:
        """EtherCAT has no NMT reset: never called."""

    def set_operational(self, operational: bool) -> None:
        """The EtherCAT state entered (True) or left (False) OP."""
        new = NmtState.OPERATIONAL if operational else NmtState.PRE_OPERATIONAL
        old, self.nmt_state = self.nmt_state, new
        if old is not new:
            for hook in self._nmt_hooks:
                hook(old, new)

    def start(self) -> None:
        """Nothing to boot: the slave is the communication side."""

    def stop(self) -> None:
        """Nothing to release."""
        self.running = False


class _AxisMirror:
    """Axes 1..3: the axis's own dictionary and its rows in the slave's dictionary (+0x800 n) hold
    the same values. CoE downloads go to the axis through its hooks (an abort refuses the write),
    process data outputs are put into it, everything the drive publishes is put into the slave's
    rows (and so into the inputs)."""

    def __init__(self, slave_od: ObjectDictionary, axis_od: ObjectDictionary, off: int) -> None:
        self.slave_od = slave_od
        self.axis_od = axis_od
        self.off = off
        for (index, sub) in axis_od.entries:
            axis_od.subscribe((index, sub), self._to_slave)
            slave_od.subscribe((index + off, sub), self._to_axis)
        for index in axis_od.objects:
            slave_od.on_write(index + off, self._download)

    def _to_slave(self, key: tuple[int, int], value: Any) -> None:
        self.slave_od.put(key[0] + self.off, key[1], value)

    def _to_axis(self, key: tuple[int, int], value: Any) -> None:
        self.axis_od.put(key[0] - self.off, key[1], value)

    def _download(self, index: int, subindex: int, value: Any) -> None:
        axis_od = self.axis_od
        axis_od.store(axis_od.entries[(index - self.off, subindex)], value)


class DriveApplication(SlaveApplication):
    """The axes behind the ESC: CiA 402 over EtherCAT (ETG.6010) and the ETG.1020 sync modes.

    Outputs reach the axes once the frame has passed (``outputs_in_frame`` False), as a drive's
    firmware reads the SM2 buffer after its interrupt: the frame's round trip is the ESC's work only,
    and the statusword answering a controlword is in the next frame's inputs."""

    outputs_in_frame = False

    def __init__(self, axes: int = 1, params: AxisParams | None = None, serial: int = 0) -> None:
        self.n_axes = axes
        self.params = params
        self.serial = serial
        self.drives: list[Drive] = []
        self.hosts: list[CoeHost] = []
        self.axis_ods: list[ObjectDictionary] = []
        self.sync_mode = FREE_RUN
        self.cycle = 0.001
        self._sync_written = False
        self._timer: PeriodicTimer | None = None
        self._slave: Slave | None = None
        #: Outputs events since the last SYNC0 (DC) / a control period already pending (SM).
        self._outputs_seen = 0
        self._sm_pending = False
        self._armed = False
        self._last_sync0: float | None = None
        self.sync_error_counter = 0
        self._saturated_ms: list[float] = []
        self._control: list[tuple[ObjectDictionary, Entry, tuple[int, int]]] = []
        self.errors = 0

    # ------------------------------------------------------------------ construction
    def setup_od(self, slave: Slave, od: ObjectDictionary) -> None:
        """Build the axes on the slave's dictionary (axis 0) and on mirrored ones (axes 1..3),
        power them on and run them free (the drive's own 1 ms period) until SAFEOP."""
        self._slave = slave
        register = _ErrorRegister(od)
        for n in range(self.n_axes):
            if n == 0:
                axis_od = od
            else:
                axis_od = axis_rows(self.params)
                _AxisMirror(od, axis_od, AXIS_OFFSET * n)
            host = CoeHost(axis_od, CoeEmergency(slave, n, register))
            # The drive takes the part of a Node it uses from the CoE host (see CoeHost).
            drive = Drive(slave.clock, None, None, self.serial, name=f"{slave.name} axis {n + 1}",
                          params=self.params, od=axis_od, host=host)
            self.axis_ods.append(axis_od)
            self.hosts.append(host)
            self.drives.append(drive)
            self._saturated_ms.append(0.0)
        for index in (0x1C32, 0x1C33):
            od.on_write(index, self._sync_object_written)
        for drive in self.drives:
            drive.start()
            drive.set_external_cycle(True)
        self._run_free()

    def _sync_object_written(self, index: int, subindex: int, value: Any) -> None:
        if subindex == 1:
            self._sync_written = True

    def stop(self) -> None:
        """Stop the control periods (rig stop)."""
        self._stop_free()
        for drive in self.drives:
            drive.stop()

    # ------------------------------------------------------------------ control periods
    def _run_free(self) -> None:
        if self._timer is None and self._slave is not None:
            self._timer = self._slave.clock.call_every(0.001, self._period, 0.001)

    def _stop_free(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    def _period(self, dt: float) -> None:
        """One control period of every axis, then the over-current supervision."""
        for n, drive in enumerate(self.drives):
            drive.control_period(dt)
            if drive.plant.state.saturated and drive.state is PdsState.OPERATION_ENABLED:
                self._saturated_ms[n] += dt * 1000.0
                limit = int(drive.od.values[(OVERCURRENT_TIME_INDEX, 0)])
                if limit and self._saturated_ms[n] > limit:
                    self._saturated_ms[n] = 0.0
                    drive.fault(ERROR_OVERCURRENT, ERR_CURRENT)
            else:
                self._saturated_ms[n] = 0.0

    def _sm_period(self) -> None:
        self._sm_pending = False
        self._period(self.cycle)

    # ------------------------------------------------------------------ EtherCAT state machine
    def on_transition(self, slave: Slave, old: AlState, new: AlState) -> int:
        """PREOP -> SAFEOP: the mapping (no object twice: ETG.1000.6 0x0025 / 0x0024) and the
        sync mode (ETG.1020: 0x0028 not supported, 0x0030 DC mode without SYNC0, 0x0035 cycle
        below 0x1C32:05)."""
        if not (old == AlState.PREOP and new == AlState.SAFEOP):
            return 0
        for mapping, code in ((slave.outputs_map, AlStatusCode.INVALID_OUTPUT_MAPPING),
                              (slave.inputs_map, AlStatusCode.INVALID_INPUT_MAPPING)):
            keys = [m.key for m in mapping]
            if len(keys) != len(set(keys)):
                return code
        od = slave.od
        dc_on = slave.esc.sync0_active
        if self._sync_written:
            mode = int(od.values[(0x1C32, 1)])
        else:
            mode = DC_SYNC0 if dc_on else SM_SYNC if slave.output_bytes else FREE_RUN
        if mode not in (FREE_RUN, SM_SYNC, DC_SYNC0):
            return AlStatusCode.SYNCMODE_NOT_SUPPORTED
        if mode == DC_SYNC0:
            if not dc_on:
                return AlStatusCode.INVALID_DC_SYNC_CONFIG
            cycle_ns = slave.esc.sync0_cycle_ns
            if cycle_ns < int(od.values[(0x1C32, 5)]):
                od.put(0x1C32, 12, (int(od.values[(0x1C32, 12)]) + 1) & 0xFFFF)
                return AlStatusCode.INVALID_DC_CYCLE_TIME
            od.put(0x1C32, 2, cycle_ns)
            od.put(0x1C33, 2, cycle_ns)
        self.sync_mode = mode
        od.put(0x1C32, 1, mode)
        od.put(0x1C33, 1, SM2_EVENT if mode == SM_SYNC else mode)
        return 0

    def on_state(self, slave: Slave, old: AlState, new: AlState, code: int) -> None:
        """SAFEOP: the sync mode takes over the control periods and the counters restart; leaving
        OP: outputs are zeros, applied as a controlword 0 (disable voltage); INIT: free run."""
        od = slave.od
        if new == AlState.SAFEOP and old == AlState.PREOP:
            for index in (0x1C32, 0x1C33):
                od.put(index, 11, 0)
                od.put(index, 12, 0)
                od.put(index, 32, False)
            self.sync_error_counter = 0
            self._outputs_seen = 0
            self._armed = False
            self._last_sync0 = None
            self.cycle = int(od.values[(0x1C32, 2)]) / 1e9 or 0.001
            if self.sync_mode == FREE_RUN:
                self._run_free()
            else:
                self._stop_free()
            self._control = [(self.axis_ods[n], self.axis_ods[n].entries[(m.index - AXIS_OFFSET * n, m.subindex)],
                              m.key)
                             for m in slave.outputs_map
                             for n in [self._axis_of(m.index)]
                             if n is not None and (m.index - AXIS_OFFSET * n) in self.axis_ods[n].intercepted]
            for m in slave.inputs_map:   # the image starts with the present values
                if m.key in od.entries:
                    slave.write_input(m.index, m.subindex, od.values[m.key])
        if new in (AlState.INIT, AlState.PREOP, AlState.BOOT):
            self._run_free()
            if new == AlState.INIT:
                self._sync_written = False
        if (new == AlState.OP) != (old == AlState.OP):
            for host in self.hosts:
                host.set_operational(new == AlState.OP)
        if old == AlState.OP and new != AlState.OP:
            self._apply_control(slave)

    def _axis_of(self, index: int) -> int | None:
        """The axis whose row ``index`` is (axis n: a drive row + 0x800 n)."""
        rows = self.axis_ods[-1].objects if self.n_axes > 1 else self.axis_ods[0].objects
        for n in range(self.n_axes - 1, -1, -1):
            if index - AXIS_OFFSET * n in rows:
                return n
        return None

    def _apply_control(self, slave: Slave) -> None:
        """The mapped outputs with device hooks (controlword, mode) applied as a CANopen RPDO
        applies them: every cycle, in mapping order."""
        values = slave.od.values
        for axis_od, entry, key in self._control:
            try:
                axis_od.store(entry, values[key])
            except SdoAbort:
                self.errors += 1

    def on_outputs(self, slave: Slave, data: bytes) -> None:
        """New outputs (OP): controlword and mode applied now; SM-synchronous mode runs a control
        period right after the frame; DC mode counts the event for the next SYNC0."""
        self._apply_control(slave)
        self._armed = True
        mode = self.sync_mode
        if mode == SM_SYNC:
            if self._sm_pending:
                # the previous event's control period has not run yet (frames back to back):
                # run it now, so the axis runs one period per master cycle whatever the jitter
                self._count(slave, 12)
                self._period(self.cycle)
            else:
                self._sm_pending = True
                slave.clock.call_soon(self._sm_period)
        elif mode == DC_SYNC0:
            self._outputs_seen += 1
            if self._outputs_seen > 1:
                self._count(slave, 12)      # two set-points within one SYNC0 cycle

    def on_sync0(self, slave: Slave, t: float) -> None:
        """DC mode: the missed-event supervision, then a control period (after 0x1C32:03 shift)."""
        if self.sync_mode != DC_SYNC0 or slave.state not in (AlState.SAFEOP, AlState.OP):
            return
        if slave.state == AlState.OP and self._armed:
            if self._outputs_seen == 0:
                self._count(slave, 11)
                self.sync_error_counter += 3
                if self.sync_error_counter > int(slave.od.values[(0x10F1, 2)]):
                    slave.od.put(0x1C32, 32, True)
                    slave.od.put(0x1C33, 32, True)
                    slave.fault(AlStatusCode.SYNCHRONIZATION_ERROR)
                    return
            elif self.sync_error_counter:
                self.sync_error_counter -= 1
        self._outputs_seen = 0
        # pulses the ESC merged while the PDI was busy (shared CPU) still are control periods:
        # the plant keeps the time of the SYNC0 train (at most 100 periods at once)
        last, self._last_sync0 = self._last_sync0, t
        periods = 1 if last is None else max(1, min(100, round((t - last) / self.cycle)))
        shift = int(slave.od.values[(0x1C32, 3)]) / 1e9
        for _ in range(periods):
            if shift > 0:
                slave.clock.call_later(shift, self._period, self.cycle)
            else:
                self._period(self.cycle)

    @staticmethod
    def _count(slave: Slave, sub: int) -> None:
        od = slave.od
        for index in (0x1C32, 0x1C33):
            od.put(index, sub, (int(od.values[(index, sub)]) + 1) & 0xFFFF)


class EthercatDrive:
    """The slave and its axes (what tests and the rig participant hold)."""

    def __init__(self, clock: Clock, name: str = "GL-Drive CiA402", serial: int = 0, axes: int = 1,
                 params: AxisParams | None = None) -> None:
        self.app = DriveApplication(axes, params, serial)
        self.slave = Slave(clock, drive_description(name, serial, axes, params), self.app, name=name)

    @property
    def drives(self) -> list[Drive]:
        """The axes' CiA 402 drives (axis 0 first)."""
        return self.app.drives

    @property
    def drive(self) -> Drive:
        """Axis 0: what `gatewaylab fault drive-fault NAME` (rig.faults) acts on."""
        return self.app.drives[0]

    def stop(self) -> None:
        """Stop the control periods."""
        self.app.stop()


def create_drive_slave(clock: Clock, name: str = "GL-Drive CiA402", serial: int = 0, axes: int = 1,
                       params: AxisParams | None = None) -> Slave:
    """An ``ethercat_drive`` slave ready to be put in a segment (its axes: ``slave.app.drives``)."""
    return EthercatDrive(clock, name, serial, axes, params).slave
