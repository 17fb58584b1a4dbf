"""The ECAN-Lite's device model bound into a slave's dictionary: :class:`McanModel` holds the four MCAN
channels (:mod:`.mcan.channel`) plus the system objects (``system.py``), the flash image
(``flash.py``) and the FoE update (``ota.py``), lists every object it owns
(:meth:`McanModel.object_defs`) and wires their hooks -- validators, reactions to the apply /
flash / filter-window commands, read hooks of 0x9000 / 0x9020 -- into a slave's dictionary
(:meth:`McanModel.install`). The system objects call back only through the narrow
:class:`~.model_port.ModelPort`, so ``system.py`` never imports this file.
Sans-I/O: the bus calls in on the injected clock; nothing sleeps.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from gatewaylab.bus.bus import Controller
from gatewaylab.common.clock import Clock
from gatewaylab.common.errors import ConfigError
from gatewaylab.devices.ecanlite.flash import FileFlash, FlashMedium, MemoryFlash
from gatewaylab.devices.ecanlite.mcan.channel import McanChannel
from gatewaylab.devices.ecanlite.mcan.datapath import DataPathPolicy, PolicyError
from gatewaylab.devices.ecanlite.mcan.filters import EMPTY_FILTER, EntryStatus, FilterElement
from gatewaylab.devices.ecanlite.mcan.layout import ApplyStatus
from gatewaylab.devices.ecanlite.mcan.objects import (
    CHANNELS,
    CONFIG_BASE,
    CONFIG_DEFAULTS,
    CONFIG_PERSISTED,
    CONFIG_ROWS,
    DIAG_BASE,
    DIAG_ROWS,
    EXT_LIST_MAX,
    INFO_BASE,
    INFO_ROWS,
    POLICY_BASE,
    POLICY_DEFAULTS,
    POLICY_PERSISTED,
    POLICY_ROWS,
    STD_LIST_MAX,
    rows_object,
)
from gatewaylab.devices.ecanlite.ota import FirmwareVersion, OtaError, unpack
from gatewaylab.devices.ecanlite.system import SystemModel
from gatewaylab.ethercat.description import ObjectDef
from gatewaylab.od import Entry, ObjectDictionary, SdoAbort, SdoAbortCode

if TYPE_CHECKING:
    from gatewaylab.ethercat.foe import FoeHandler
    from gatewaylab.ethercat.slave import Slave

__all__ = ["FACTORY_VERSION", "McanModel"]

#: The firmware a device runs before any OTA update (0xF000:05 = 0x0103, :06 = 0x2100).
FACTORY_VERSION = FirmwareVersion(1, 3, 0x2100)


def _abort(code: SdoAbortCode, text: str) -> SdoAbort:
    return SdoAbort(code, text)


def _put(od: ObjectDictionary, index: int, values: Mapping[int, int]) -> None:
    keys = [(index, s) for s in values]
    od.put_many(keys, [v & 0xFFFFFFFF for v in values.values()])


class McanModel:
    """The four MCAN channels, the system objects, flash and FoE update of one ECAN-Lite."""

    def __init__(self, clock: Clock, controllers: Sequence[Controller | None],
                 flash_path: Path | FlashMedium | None = None, *, serial: int = 0,
                 hardware_revision: int = 0) -> None:
        """``flash_path``: the configuration flash file (the APP partition is ``PATH.app`` next to
        it), None for flash in memory, or a :class:`~.flash.FlashMedium` (e.g. the previous
        model's ``flash``, so a reset keeps an in-memory flash and firmware)."""
        if len(controllers) > CHANNELS:
            raise ConfigError(f"the ECAN-Lite has {CHANNELS} MCAN channels, got {len(controllers)} controllers")
        self.clock = clock
        ctrls = list(controllers) + [None] * (CHANNELS - len(controllers))
        #: The controller on each fixed pin group; logical channel k uses group (k + rotation) % 4.
        self.pins: tuple[Controller | None, ...] = tuple(ctrls)
        self.rotation = 0
        self.channels: list[McanChannel] = [McanChannel(k, clock, c) for k, c in enumerate(ctrls)]
        if flash_path is None:
            self.flash: FlashMedium = MemoryFlash()
        elif isinstance(flash_path, (str, Path)):
            self.flash = FileFlash(flash_path)
        else:
            self.flash = flash_path
        #: The running firmware: the installed APP package, else the factory firmware.
        self.version: FirmwareVersion = FACTORY_VERSION
        try:
            app = self.flash.read_app()
            if app is not None:
                self.version = unpack(app).version
        except (OSError, OtaError):
            pass
        self.system: SystemModel = SystemModel(self, serial=serial, hardware_revision=hardware_revision)
        self.od: ObjectDictionary | None = None
        self.system.power_on()

    # -- contract --------------------------------------------------------------------------------
    @property
    def version_string(self) -> str:
        """0x100A text: '1.3 build 0x2100' (the device's version_string format)."""
        return str(self.version)

    def object_defs(self) -> tuple[ObjectDef, ...]:
        """Every object this module owns (0x8000..0x8004, 0x8020..0x8024, 0x8030, 0x9000..0x9003,
        0x9020..0x9023, 0xA000..0xA003, 0xB000, 0xF000)."""
        out: list[ObjectDef] = []
        for k in range(CHANNELS):
            out.append(rows_object(CONFIG_BASE + k, f"MCAN{k} Channel Config", CONFIG_ROWS))
            out.append(rows_object(POLICY_BASE + k, f"MCAN{k} Data Path Control", POLICY_ROWS))
            out.append(rows_object(INFO_BASE + k, f"MCAN{k} Channel Information", INFO_ROWS))
            out.append(rows_object(DIAG_BASE + k, f"MCAN{k} Data Path Diagnostics", DIAG_ROWS))
        out.extend(self.system.object_defs())
        return tuple(sorted(out, key=lambda o: o.index))

    def install(self, slave: Slave | None, od: ObjectDictionary) -> None:
        """Put the running configuration into ``od`` and wire the hooks (validators, reactions,
        read hooks). Called from the device's ``SlaveApplication.setup_od``; again after a reset
        with the new dictionary (the same dictionary twice only refreshes the values)."""
        hook = od is not self.od
        self.od = od
        for ch in self.channels:
            k = ch.index
            rt_values = ch.runtime.settings.values if ch.runtime is not None else CONFIG_DEFAULTS
            _put(od, CONFIG_BASE + k, {s: rt_values.get(s, CONFIG_DEFAULTS[s]) for s in CONFIG_PERSISTED})
            _put(od, POLICY_BASE + k, self._policy_values(ch.policy))
            if not hook:
                continue
            od.add_validator(CONFIG_BASE + k, self._config_validator)
            od.add_reaction(CONFIG_BASE + k, self._config_reaction)
            od.add_reaction(POLICY_BASE + k, self._policy_reaction)
            od.on_read(INFO_BASE + k, self._info_read)
            od.on_read(DIAG_BASE + k, self._diag_read)
        self.system.install(slave, od, hook=hook)

    def on_cycle(self, t: float) -> None:
        """Per-cycle tick (TX backoff); call once per process data cycle."""
        for ch in self.channels:
            ch.on_cycle(t)

    def ota_handler(self, on_accepted: Callable[[], None]) -> FoeHandler:
        """The FoE handler for ``ecan_lite_app`` (password 0): a good package takes the new
        version and calls ``on_accepted`` (the device resets)."""
        return self.system.ota_handler(on_accepted)

    def rotate(self, rotation: int) -> None:
        """0x8000:12 CAN pin rotation: logical channel k moves to pin group (k + rotation) % 4."""
        rotation %= CHANNELS
        if rotation == self.rotation:
            return
        for ch in self.channels:
            ch.release()
        self.rotation = rotation
        for ch in self.channels:
            ch.bind(self.pins[(ch.index + rotation) % CHANNELS])

    def close(self) -> None:
        """The firmware stops (device reset): the controllers forget this model's callbacks and
        their queued frames."""
        for ch in self.channels:
            ch.unhook()
            if ch.controller is not None:
                ch.controller.flush_tx()
            ch.path.forget_tx()

    def reset(self) -> None:
        """A device reset (after an OTA update or 0x8000:01): channels restart from the flash image."""
        for ch in self.channels:
            ch.std_filters = [EMPTY_FILTER] * STD_LIST_MAX
            ch.ext_filters = [EMPTY_FILTER] * EXT_LIST_MAX
            ch.runtime = None
            ch.clear_diagnostics()
            ch.path.clear_rx()
        self.system.power_on()

    # -- settings <-> dictionary -----------------------------------------------------------------
    @staticmethod
    def _policy_values(p: DataPathPolicy) -> dict[int, int]:
        return {1: int(p.enable), 4: p.rx_drain_min, 5: p.rx_drain_max, 6: p.rx_budget_policy,
                7: p.rx_cache_depth, 8: p.rx_overflow,
                9: p.critical, 10: p.id_priority, 11: p.tx_budget_min, 12: p.tx_budget_max, 13: p.tx_overflow,
                14: p.busoff_recovery, 15: p.backoff_base, 16: p.degraded_threshold, 20: p.control_word}

    def config_values(self, k: int) -> dict[int, int]:
        """The requested 0x800x values of channel ``k`` (the dictionary's, or the active ones)."""
        od = self.od
        index = CONFIG_BASE + k
        if od is not None:
            return {s: int(od.values[(index, s)]) for s in CONFIG_DEFAULTS}
        ch = self.channels[k]
        base = ch.runtime.settings.values if ch.runtime is not None else CONFIG_DEFAULTS
        return {s: int(base.get(s, CONFIG_DEFAULTS[s])) for s in CONFIG_DEFAULTS}

    def policy_values(self, k: int) -> dict[int, int]:
        """The requested 0x802x values of channel ``k``."""
        od = self.od
        if od is not None:
            return {s: int(od.values[(POLICY_BASE + k, s)]) for s in POLICY_DEFAULTS}
        return self._policy_values(self.channels[k].policy)

    def apply_channel(self, k: int) -> ApplyStatus:
        """0x800x:01 = 1."""
        ch = self.channels[k]
        status = ch.apply(ch.settings_from(self.config_values(k)))
        self._publish_config_status(k, apply_status=status)
        return status

    def apply_policy(self, k: int) -> int:
        """0x802x:02 = 1: 0 OK, 1 fail (old policy kept)."""
        ch = self.channels[k]
        try:
            policy = DataPathPolicy.from_values(self.policy_values(k))
        except PolicyError:
            status = 1
        else:
            ch.apply_policy(policy)
            status = 0
        if self.od is not None:
            _put(self.od, POLICY_BASE + k, {3: status, 20: ch.policy.control_word})
        return status

    def load_channel_settings(self, k: int, values: Mapping[int, int], std: Sequence[FilterElement] = (),
                              ext: Sequence[FilterElement] = ()) -> ApplyStatus:
        """Settings from flash or the factory defaults become channel ``k``'s requested
        configuration (dictionary and filter lists) and are applied."""
        ch = self.channels[k]
        ch.std_filters = (list(std) + [EMPTY_FILTER] * STD_LIST_MAX)[:STD_LIST_MAX]
        ch.ext_filters = (list(ext) + [EMPTY_FILTER] * EXT_LIST_MAX)[:EXT_LIST_MAX]
        full = {**CONFIG_DEFAULTS, **{s: int(values[s]) for s in CONFIG_PERSISTED if s in values}}
        if self.od is not None:
            _put(self.od, CONFIG_BASE + k, {s: full[s] for s in CONFIG_PERSISTED})
        status = ch.apply(ch.settings_from(full))
        self._publish_config_status(k, apply_status=status)
        return status

    def load_policy_values(self, k: int, values: Mapping[int, int]) -> int:
        """0x802x values from flash or the defaults become channel ``k``'s requested policy and
        are applied (0 OK, 1 fail: the old policy stays)."""
        full = {**POLICY_DEFAULTS, **{s: int(values[s]) for s in POLICY_PERSISTED if s in values}}
        if self.od is not None:
            _put(self.od, POLICY_BASE + k, {s: full[s] for s in POLICY_PERSISTED})
        ch = self.channels[k]
        try:
            ch.apply_policy(DataPathPolicy.from_values(full))
            status = 0
        except PolicyError:
            status = 1
        if self.od is not None:
            _put(self.od, POLICY_BASE + k, {3: status, 20: ch.policy.control_word})
        return status

    def _publish_config_status(self, k: int, *, apply_status: int | None = None,
                               flash_status: int | None = None) -> None:
        if self.od is None:
            return
        index = CONFIG_BASE + k
        values: dict[int, int] = {5: (int(self.od.values[(index, 5)]) + 1) & 0xFFFFFFFF}
        if apply_status is not None:
            values[2] = int(apply_status)
        if flash_status is not None:
            values[4] = int(flash_status)
        _put(self.od, index, values)

    # -- hooks -------------------------------------------------------------------------------------
    def _config_validator(self, entry: Entry, value: Any) -> None:
        sub = entry.subindex
        if sub == 49 and int(value) > STD_LIST_MAX:
            raise _abort(SdoAbortCode.VALUE_TOO_HIGH, f"at most {STD_LIST_MAX} standard filters")
        if sub == 55 and int(value) > EXT_LIST_MAX:
            raise _abort(SdoAbortCode.VALUE_TOO_HIGH, f"at most {EXT_LIST_MAX} extended filters")

    def _config_reaction(self, entry: Entry, value: Any) -> None:
        k = entry.index - CONFIG_BASE
        sub = entry.subindex
        od = self.od
        assert od is not None
        if sub == 1:
            od.put(entry.index, 1, 0)
            if int(value) == 1:
                self.apply_channel(k)
            elif int(value) != 0:
                self._publish_config_status(k, apply_status=ApplyStatus.FAIL)
        elif sub == 3:
            od.put(entry.index, 3, 0)
            if int(value):
                status = self.system.channel_flash(k, int(value))
                self._publish_config_status(k, flash_status=status)
        elif sub in (45, 46):
            od.put(entry.index, sub, 0)
            self._entry_command(k, extended=sub == 46, cmd=int(value))

    def _entry_command(self, k: int, *, extended: bool, cmd: int) -> None:
        od = self.od
        assert od is not None
        index = CONFIG_BASE + k
        ch = self.channels[k]
        idx_sub, status_sub, base = (44, 48, 56) if extended else (43, 47, 50)
        current = int(od.values[(index, idx_sub)])
        limit = EXT_LIST_MAX if extended else STD_LIST_MAX
        lst = ch.filters(extended)
        if cmd == 0:
            status = EntryStatus.OK
        elif cmd not in (1, 2, 3):
            status = EntryStatus.COMMAND_INVALID
        elif current >= limit:
            status = EntryStatus.INDEX_INVALID
        else:
            status = EntryStatus.OK
            if cmd == 1:
                f = lst[current]
                _put(od, index, {base: f.type, base + 1: f.action, base + 2: f.sync, base + 3: f.id1,
                                 base + 4: f.id2})
            elif cmd == 2:
                g = od.values
                lst[current] = FilterElement(int(g[(index, base)]) & 3, int(g[(index, base + 1)]) & 7,
                                             int(g[(index, base + 2)]), int(g[(index, base + 3)]),
                                             int(g[(index, base + 4)]))
            else:
                lst[current] = EMPTY_FILTER
        od.put(index, status_sub, int(status))

    def _policy_reaction(self, entry: Entry, value: Any) -> None:
        if entry.subindex == 2:
            assert self.od is not None
            self.od.put(entry.index, 2, 0)
            k = entry.index - POLICY_BASE
            if int(value) == 1:
                self.apply_policy(k)
            elif int(value) != 0:
                _put(self.od, entry.index, {3: 1})

    def _info_read(self, index: int, subindex: int) -> None:
        assert self.od is not None
        ch = self.channels[index - INFO_BASE]
        values = ch.info()
        if subindex == 12:
            values[12] = ch.take_events()
        else:
            values.pop(12)
        _put(self.od, index, values)

    def _diag_read(self, index: int, subindex: int) -> None:
        assert self.od is not None
        _put(self.od, index, self.channels[index - DIAG_BASE].diagnostics())
