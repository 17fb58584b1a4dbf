"""An EtherCAT slave built from an ESI device: the slave, its process data rules and PDO checks.

Inputs keep their ESI defaults and outputs are stored into their objects unless ``[device.behaviour]``
rules (``gatewaylab.plugin.behaviour``) move them. The rules run once per process data cycle: on the
outputs SyncManager event (inside the frame, before the same LRW reads the inputs, so an echo of an
output is in the inputs of the very frame that carried it) for a device with outputs, on the inputs
SyncManager read (refreshed for the next cycle) for a device without outputs. Both events exist
whatever the master's DC mode is; a SYNC0-driven evaluation would leave SM-synchronous and free-run
masters without changes.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any

from mypy_extensions import mypyc_attr

from gatewaylab.common.clock import Clock
from gatewaylab.devices.esi.esm import EsmTimer
from gatewaylab.devices.esi.files import EsiFiles
from gatewaylab.devices.esi.reader import EsiDevice, EsiError, apply_dictionary, identity_overrides
from gatewaylab.ethercat.description import DeviceDescription
from gatewaylab.ethercat.esc import AlState
from gatewaylab.ethercat.slave import Slave, SlaveApplication
from gatewaylab.od import Entry, ObjectDictionary, SdoAbort, SdoAbortCode
from gatewaylab.plugin.behaviour import Behaviour

__all__ = ["EsiApplication", "esi_description", "esi_slave"]


def esi_description(device: EsiDevice, serial: int | None = None, sii: bytes | None = None) -> DeviceDescription:
    """The description a slave runs from: the ESI's, its dictionary laid over the standard objects,
    ``serial`` in SII and 0x1018:04, the SII ``sii`` (a dump) or the ESI's ``<Eeprom><Data>`` when given."""
    overlay = identity_overrides(serial)

    def extend(od: ObjectDictionary) -> None:
        apply_dictionary(od, device)
        overlay(od)

    image = sii if sii is not None else device.sii
    if image is not None and len(image) < 0x80:
        raise EsiError(f"{device.source}: the SII image has {len(image)} bytes, shorter than the fixed 128")
    return replace(device.desc, serial=serial or 0, extend_od=extend, sii_image=image)


@mypyc_attr(allow_interpreted_subclasses=True)
class EsiApplication(SlaveApplication):
    """Behaviour rules once per cycle, PDO configuration checks (ETG.1000.6 PDO mapping / assignment), the
    ESI's state machine timeouts for transitions the rig makes slow (:mod:`gatewaylab.devices.esi.esm`)."""

    def __init__(self, device: EsiDevice, behaviour: Behaviour | None = None,
                 transition_ms: Mapping[tuple[AlState, AlState], float] | None = None) -> None:
        self.device = device
        self.behaviour = behaviour
        self.clock: Clock | None = None
        self.has_outputs = bool(device.desc.rx_pdos)
        self.esm = EsmTimer(device.timeouts, transition_ms or {})

    def setup_od(self, slave: Slave, od: ObjectDictionary) -> None:
        """Subindex 0 of a mapping or assignment object: the objects it enables must exist and fit the
        SyncManager (0x06040041 not mappable, 0x06040042 PDO length exceeded)."""
        self.clock = slave.clock
        desc = self.device.desc
        limits = {True: self.device.outputs_max, False: self.device.inputs_max}

        def bits_of_pdo(pdo: int, n: int | None = None) -> int:
            count = int(od.get(pdo, 0)) if n is None else n
            total = 0
            for j in range(1, count + 1):
                if (pdo, j) not in od.entries:
                    raise SdoAbort(SdoAbortCode.OBJECT_NOT_MAPPABLE, f"0x{pdo:04X}:{j} does not exist")
                value = int(od.get(pdo, j))
                target, sub, bits = value >> 16, (value >> 8) & 0xFF, value & 0xFF
                if target and (target, sub) not in od.entries:
                    raise SdoAbort(SdoAbortCode.OBJECT_NOT_MAPPABLE, f"0x{target:04X}:{sub} does not exist")
                total += bits
            return total

        def check(rx: bool, bits: int) -> None:
            limit = limits[rx]
            if limit is not None and bits > 8 * limit:
                raise SdoAbort(SdoAbortCode.PDO_LENGTH_EXCEEDED,
                               f"{bits} bits exceed the {'outputs' if rx else 'inputs'} SyncManager ({limit} bytes)")

        def mapping(entry: Entry, value: Any) -> None:
            if entry.subindex == 0 and int(value):
                check(entry.index < 0x1A00, bits_of_pdo(entry.index, int(value)))

        def assignment(entry: Entry, value: Any) -> None:
            if entry.subindex != 0 or not int(value):
                return
            total = 0
            for i in range(1, int(value) + 1):
                pdo = int(od.get(entry.index, i))
                if pdo not in od.objects:
                    raise SdoAbort(SdoAbortCode.VALUE_RANGE_EXCEEDED, f"no PDO 0x{pdo:04X} to assign")
                total += bits_of_pdo(pdo)
            check(entry.index == 0x1C12, total)

        if desc.coe:
            for pdo in (*desc.rx_pdos, *desc.tx_pdos):
                if pdo.index in od.objects:
                    od.add_validator(pdo.index, mapping)
            for index in (0x1C12, 0x1C13):
                if index in od.objects:
                    od.add_validator(index, assignment)

    def _tick(self) -> None:
        if self.behaviour is not None and self.clock is not None:
            self.behaviour.apply(self.clock.now())

    def on_outputs(self, slave: Slave, data: bytes) -> None:
        """Outputs stored into their objects (by the slave): the rules for this cycle."""
        self._tick()

    def on_inputs_read(self, slave: Slave) -> None:
        """A device without outputs: the rules for the next cycle."""
        if not self.has_outputs or slave.state != AlState.OP:
            self._tick()

    def on_transition(self, slave: Slave, old: AlState, new: AlState) -> int:
        """At once, or pending for the application's time (``transition_ms``) within the ESI's timeout."""
        return self.esm.on_transition(slave.clock, slave, old, new)

    def on_state(self, slave: Slave, old: AlState, new: AlState, code: int) -> None:
        """Entering SAFEOP: the inputs the master reads first already follow the rules."""
        if new == AlState.SAFEOP and old == AlState.PREOP:
            self._tick()


def esi_slave(clock: Clock, device: EsiDevice, name: str, *, serial: int | None = None,
              sii_path: Path | None = None, behaviour: Behaviour | None = None,
              transition_ms: Mapping[tuple[AlState, AlState], float] | None = None,
              files: EsiFiles | None = None) -> Slave:
    """A slave of ``device`` (rules applied by its :class:`EsiApplication`; set ``behaviour`` later with
    ``slave.app.behaviour`` when the rules need the slave's dictionary first); ``transition_ms`` the
    application's time per upward transition in seconds (:func:`gatewaylab.devices.esi.esm.parse_transition_ms`);
    ``files`` the rig build's ESI files: the dictionary is a copy of the one they built for ``device``."""
    sii = None
    if sii_path is not None:
        try:
            sii = sii_path.read_bytes()
        except OSError as exc:
            raise EsiError(f"{sii_path}: cannot read it ({exc.strerror or exc})") from None
    desc = esi_description(device, serial, sii)
    od = files.dictionary(device, desc, identity_overrides(serial)) if files is not None else None
    return Slave(clock, desc, EsiApplication(device, behaviour, transition_ms), name=name, od=od)
