"""The object dictionary as data: rows of :class:`Entry` bound to typed storage, with hooks.

One :class:`ObjectDictionary` serves a CANopen node (``canopen.node``) and an EtherCAT slave's
CoE server (``ethercat.slave``) alike; what differs per protocol (may this entry be written in the
present NMT / EtherCAT state?) is a small :class:`AccessPolicy` the caller passes. Values are
typed Python values in ``values`` keyed by (index, subindex); :meth:`put` is the device's own
write and the one change notification (:meth:`subscribe`); :meth:`write` is the remote write with
the device's validators, commands, write hooks and reactions; :meth:`read` the remote read with
its read hooks. EDS/DCF import and export live in :mod:`.eds` (``export_eds(od)``, ``import_eds(text)``:
the format knows the dictionary, not the other way round), the ESI dictionary in :mod:`.esi`.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import replace
from typing import Any, Final, Protocol

from gatewaylab.common.errors import ConfigError
from gatewaylab.od.aborts import SdoAbort, SdoAbortCode
from gatewaylab.od.types import Access, DataType, Entry, KeyObject, ObjectCode, OdObject, coerce, decode, encode

Key = tuple[int, int]
#: ``listener((index, subindex), value)`` after a value changed.
Listener = Callable[[Key, Any], None]
#: ``validator(entry, value)`` may refuse a remote write with :class:`SdoAbort`; also the
#: signature of reactions (after the store) and commands (instead of the store).
Validator = Callable[[Entry, Any], None]
#: ``hook(index, subindex, value)`` after a remote write was stored; raising undoes it.
WriteHook = Callable[[int, int, Any], None]
#: ``hook(index, subindex)`` before a remote read: refresh the value with :meth:`put`.
ReadHook = Callable[[int, int], None]
#: Where a hook applies: one index or a range of indexes (also objects added later).
Where = int | range

#: What :meth:`ObjectDictionary.put_many` compares with when a key holds no value (equal to nothing).
_ABSENT: Final = object()


class AccessPolicy(Protocol):
    """A protocol's access rules for remote reads and writes (NMT state, EtherCAT state)."""

    def check_read(self, entry: Entry) -> None:
        """Raise :class:`SdoAbort` when ``entry`` may not be read now."""

    def check_write(self, entry: Entry, data: bytes) -> None:
        """Raise :class:`SdoAbort` when ``data`` may not be written to ``entry`` now."""


class ObjectDictionary:
    """Rows of :class:`Entry` grouped in :class:`OdObject`, the current values and the hooks."""

    def __init__(self, node_id: int | None = None) -> None:
        self.objects: dict[int, OdObject] = {}
        self.entries: dict[Key, Entry] = {}
        #: The raw value store; hot paths read it directly. Write through :meth:`put`.
        self.values: dict[Key, Any] = {}
        #: Node-id used to resolve ``$NODEID`` defaults when values are (re)initialised.
        self.node_id = node_id
        #: Free-form [DeviceInfo] fields for EDS export (VendorName, ProductName, ...).
        self.device_info: dict[str, str] = {}
        #: Name of the node or slave whose hooks this dictionary holds (one owner per dictionary).
        self.owner: str | None = None
        #: keyed by the entries' own key objects (:attr:`Entry.key`, see put_many) or equal tuples
        self._listeners: dict[Any, list[Listener]] = {}
        self._validators: dict[int, list[Validator]] = {}
        self._reactions: dict[int, list[Validator]] = {}
        self._commands: dict[int, Validator] = {}
        self._write_hooks: dict[int, list[WriteHook]] = {}
        self._read_hooks: dict[int, list[ReadHook]] = {}
        #: Indexes with a command, validator, write hook or reaction (others are stored directly).
        self.intercepted: set[int] = set()
        #: Hooks registered for ranges, applied to objects added later too.
        self._range_hooks: list[tuple[range, Callable[[int], None]]] = []

    # -- building ------------------------------------------------------------------------------
    def _add_entry(self, obj: OdObject, entry: Entry) -> Entry:
        obj.entries[entry.subindex] = entry
        key = entry.key     # the one tuple object both tables hold (see Entry.key)
        entries: dict[Any, Entry] = self.entries
        values: dict[Any, Any] = self.values
        entries[key] = entry
        values[key] = coerce(entry, entry.default_for(self.node_id))
        return entry

    def _new_object(self, index: int, name: str, code: ObjectCode) -> OdObject:
        if not 0 < index <= 0xFFFF:
            raise ConfigError(f"index 0x{index:X} out of range")
        if index in self.objects:
            raise ConfigError(f"object 0x{index:04X} already exists")
        obj = OdObject(index, name, code, {})
        self.objects[index] = obj
        for where, register in self._range_hooks:
            if index in where:
                register(index)
        return obj

    def add_variable(self, index: int, name: str, data_type: DataType, access: Access = Access.RW,
                     default: Any = None, *, pdo_mappable: bool = False, low: float | None = None,
                     high: float | None = None, nodeid_offset: bool = False,
                     preop_only: bool = False, max_length: int | None = None) -> Entry:
        """Add a VAR object (subindex 0). ``max_length``: a string's size in bytes (see :class:`Entry`)."""
        obj = self._new_object(index, name, ObjectCode.VAR)
        return self._add_entry(obj, Entry(index, 0, name, DataType(data_type), access, pdo_mappable,
                                          default, low, high, nodeid_offset, preop_only, max_length))

    def add_record(self, index: int, name: str, code: ObjectCode = ObjectCode.RECORD) -> OdObject:
        """Add an empty RECORD (or ARRAY); fill it with :meth:`add_sub`. Subindex 0 is added for you."""
        return self._new_object(index, name, code)

    def add_sub(self, index: int, subindex: int, name: str, data_type: DataType,
                access: Access = Access.RW, default: Any = None, *, pdo_mappable: bool = False,
                low: float | None = None, high: float | None = None, nodeid_offset: bool = False,
                preop_only: bool = False, sub0_name: str = "Highest sub-index supported",
                max_length: int | None = None) -> Entry:
        """Add a subindex to a RECORD/ARRAY; subindex 0 'highest sub-index supported' follows.
        ``max_length``: a string's size in bytes (see :class:`Entry`)."""
        obj = self.objects[index]
        entry = self._add_entry(obj, Entry(index, subindex, name, DataType(data_type), access, pdo_mappable,
                                           default, low, high, nodeid_offset, preop_only, max_length))
        if subindex != 0:
            sub0 = obj.entries.get(0)
            highest = max(s for s in obj.entries if s != 0)
            if sub0 is None:
                self._add_entry(obj, Entry(index, 0, sub0_name, DataType.UNSIGNED8, Access.RO, False, highest))
            elif sub0.access is Access.RO or sub0.access is Access.CONST:
                new0 = replace(sub0, default=highest)
                obj.entries[0] = new0
                self.entries[(index, 0)] = new0
                self.values[(index, 0)] = highest
        return entry

    def add_array(self, index: int, name: str, data_type: DataType, count: int,
                  access: Access = Access.RW, default: Any = None, *, pdo_mappable: bool = False,
                  low: float | None = None, high: float | None = None,
                  sub0_access: Access = Access.RO, sub0_default: int | None = None,
                  sub_names: list[str] | None = None, defaults: list[Any] | None = None,
                  sub0_name: str = "Highest sub-index supported", preop_only: bool = False) -> OdObject:
        """Add an ARRAY with ``count`` elements of one type (``defaults`` per element if given)."""
        obj = self._new_object(index, name, ObjectCode.ARRAY)
        self._add_entry(obj, Entry(index, 0, sub0_name, DataType.UNSIGNED8,
                                   sub0_access, False, count if sub0_default is None else sub0_default,
                                   0, count if sub0_access.writable else None, preop_only=preop_only))
        for i in range(1, count + 1):
            label = sub_names[i - 1] if sub_names else f"{name} {i}"
            value = defaults[i - 1] if defaults is not None and i <= len(defaults) else default
            self._add_entry(obj, Entry(index, i, label, DataType(data_type), access, pdo_mappable,
                                       value, low, high, preop_only=preop_only))
        return obj

    def replace_entry(self, entry: Entry) -> None:
        """Swap the description of an existing entry (keeps its value when still valid)."""
        obj = self.objects[entry.index]
        obj.entries[entry.subindex] = entry
        self.entries[(entry.index, entry.subindex)] = entry

    # -- lookup ----------------------------------------------------------------------------------
    def entry(self, index: int, subindex: int) -> Entry:
        """The entry at (index, subindex), or SdoAbort 0x06020000 / 0x06090011 as CiA 301 says."""
        e = self.entries.get((index, subindex))
        if e is not None:
            return e
        if index in self.objects:
            raise SdoAbort(SdoAbortCode.SUBINDEX_DOES_NOT_EXIST, f"0x{index:04X}:{subindex:02X}")
        raise SdoAbort(SdoAbortCode.OBJECT_DOES_NOT_EXIST, f"0x{index:04X}")

    def object(self, index: int) -> OdObject:
        """The object at ``index``, or SdoAbort 0x06020000."""
        obj = self.objects.get(index)
        if obj is None:
            raise SdoAbort(SdoAbortCode.OBJECT_DOES_NOT_EXIST, f"0x{index:04X}")
        return obj

    def __contains__(self, key: Any) -> bool:
        if isinstance(key, tuple):
            return key in self.entries
        return key in self.objects

    def __iter__(self) -> Iterator[OdObject]:
        for index in sorted(self.objects):
            yield self.objects[index]

    def __len__(self) -> int:
        return len(self.objects)

    # -- typed values: the device's own access ---------------------------------------------------
    def get(self, index: int, subindex: int = 0) -> Any:
        """The typed value (no access checks)."""
        try:
            return self.values[(index, subindex)]
        except KeyError:
            self.entry(index, subindex)
            raise

    def put(self, index: int, subindex: int, value: Any, *, typed: bool = False) -> bool:
        """The device's own write (no access or limit checks, coerced to the entry's type): stores,
        returns True when the value changed and then calls the key's listeners.

        ``typed``: the caller guarantees that ``value`` already has the entry's Python type and
        fits its data type, so it is stored without coercion (see :meth:`put_many`)."""
        return self.put_many(((index, subindex),), (value,), typed=typed)

    def put_many(self, keys: Sequence[KeyObject], new: Iterable[Any], *, typed: bool = False) -> bool:
        """:meth:`put` of each value to its key, in order (the one implementation of both): a
        control loop publishes its actual values every period in one call. Returns True when
        any value changed; the listeners of a key run as soon as its value has changed.

        ``keys``: ``(index, subindex)`` tuples; the entries' own key objects (:attr:`Entry.key`)
        are found fastest. ``typed``: the caller guarantees that every value already has its
        entry's Python type and fits its data type (a control loop that rounds and saturates what
        it publishes), so values are stored without coercion; a value of the wrong type would be
        stored as it is."""
        # Any-typed keys and table: compiled, a key stays the object the caller holds (a
        # tuple[int, int] would be unboxed and boxed anew for every lookup)
        keys_: Sequence[Any] = keys
        values: dict[Any, Any] = self.values
        listeners_of = self._listeners
        changed = False
        if typed and not listeners_of:
            # nobody listens to any key (no event-driven TPDO mapped): compare and store only
            for key, value in zip(keys_, new):
                old = values.get(key, _ABSENT)
                if old is _ABSENT:
                    self._unknown(key)      # SdoAbort for an unknown key
                    old = values[key]       # an entry without a value: KeyError, as before
                if old != value:
                    values[key] = value
                    changed = True
            return changed
        for key, value in zip(keys_, new):
            old = values.get(key, _ABSENT)
            if old is _ABSENT:
                self._unknown(key)
            if old == value:
                # the value the entry holds: coerced it would be the same (a value equal to a
                # stored one converts to it), so nothing is stored and nobody is told. Control
                # loops put every actual value every period, most of them unchanged.
                continue
            if typed and old is not _ABSENT:
                values[key] = value
            else:
                value = coerce(self.entries[key], value)
                values[key] = value
                if old == value:
                    continue
            changed = True
            listeners = listeners_of.get(key) if listeners_of else None
            if listeners is not None:
                for listener in listeners:
                    listener(key, value)
        return changed

    def _unknown(self, key: Any) -> None:
        """SdoAbort for a key with no entry (put / put_many); returns when it names one whose
        value is absent (a table filled by hand)."""
        index, subindex = key
        self.entry(index, subindex)

    def set(self, index: int, subindex: int, value: Any) -> None:
        """:meth:`put` without the result (typed local access for device code)."""
        self.put(index, subindex, value)

    def subscribe(self, key: KeyObject, listener: Listener) -> Callable[[], None]:
        """``listener(key, value)`` whenever the value at ``key`` changes; returns the unsubscribe."""
        self._listeners.setdefault(key, []).append(listener)

        def unsubscribe() -> None:
            listeners = self._listeners.get(key)
            if listeners is not None and listener in listeners:
                listeners.remove(listener)
                if not listeners:
                    del self._listeners[key]
        return unsubscribe

    def _changed(self, key: Any, value: Any) -> None:
        listeners = self._listeners.get(key)
        if listeners is not None:
            for listener in listeners:
                listener(key, value)

    def get_bytes(self, index: int, subindex: int = 0) -> bytes:
        """The wire form of the present value (no access checks, no read hooks)."""
        entry = self.entry(index, subindex)
        return encode(entry, self.values[(index, subindex)])

    def bit_length(self, index: int, subindex: int) -> int:
        """Bits of the entry as its description declares them (ESI BitSize, SDO information): its
        type's size, a string's maximum length (or its present length when the device stored a
        longer value itself), the present length of a DOMAIN."""
        entry = self.entry(index, subindex)
        bits = entry.bit_length
        if bits:
            return bits
        present = 8 * len(encode(entry, self.values[(index, subindex)]))
        return max(entry.declared_bits, present)

    def reset_values(self, indices: range | None = None) -> None:
        """Put the defaults back (all, or the objects whose index is in ``indices``)."""
        for key, entry in self.entries.items():
            if indices is None or key[0] in indices:
                self.values[key] = coerce(entry, entry.default_for(self.node_id))

    def copy(self) -> ObjectDictionary:
        """An independent dictionary with the same rows and values (entries are immutable; no hooks)."""
        new = ObjectDictionary(self.node_id)
        for index, obj in self.objects.items():
            new.objects[index] = OdObject(obj.index, obj.name, obj.object_code, dict(obj.entries))
        new.entries = dict(self.entries)
        new.values = dict(self.values)
        new.device_info = dict(self.device_info)
        return new

    # -- hooks -----------------------------------------------------------------------------------
    def _register(self, where: Where, register: Callable[[int], None]) -> None:
        if isinstance(where, range):
            self._range_hooks.append((where, register))
            for index in list(self.objects):
                if index in where:
                    register(index)
        else:
            register(where)

    def add_validator(self, where: Where, validator: Validator) -> None:
        """``validator(entry, value)`` before a remote write is stored; may refuse with SdoAbort."""
        def register(index: int) -> None:
            self._validators.setdefault(index, []).append(validator)
            self.intercepted.add(index)
        self._register(where, register)

    def add_reaction(self, where: Where, reaction: Validator) -> None:
        """``reaction(entry, value)`` after a remote write was stored (apply commands, reconfigure)."""
        def register(index: int) -> None:
            self._reactions.setdefault(index, []).append(reaction)
            self.intercepted.add(index)
        self._register(where, register)

    def add_command(self, where: Where, command: Validator) -> None:
        """Remote writes run ``command(entry, value)`` and store nothing (0x1010 'save', triggers)."""
        def register(index: int) -> None:
            self._commands[index] = command
            self.intercepted.add(index)
        self._register(where, register)

    def on_write(self, where: Where, hook: WriteHook) -> None:
        """``hook(index, subindex, value)`` after a remote write was stored; raising undoes it."""
        def register(index: int) -> None:
            self._write_hooks.setdefault(index, []).append(hook)
            self.intercepted.add(index)
        self._register(where, register)

    def on_read(self, where: Where, hook: ReadHook) -> None:
        """``hook(index, subindex)`` before a remote read: status objects and counters refresh here."""
        def register(index: int) -> None:
            self._read_hooks.setdefault(index, []).append(hook)
        self._register(where, register)

    # -- remote access (SDO / CoE) -----------------------------------------------------------------
    def read(self, index: int, subindex: int, policy: AccessPolicy | None = None) -> bytes:
        """The value as an SDO upload returns it: policy, read hooks, wire form."""
        entry = self.entries.get((index, subindex)) or self.entry(index, subindex)
        if policy is not None:
            policy.check_read(entry)
        elif entry.access is Access.WO:
            raise SdoAbort(SdoAbortCode.WRITE_ONLY, f"0x{index:04X}:{subindex:02X}")
        hooks = self._read_hooks.get(index)
        if hooks is not None:
            for hook in hooks:
                hook(index, subindex)
        return encode(entry, self.values[(index, subindex)])

    def write(self, index: int, subindex: int, data: bytes, policy: AccessPolicy | None = None) -> None:
        """An SDO download: policy (access, state), length and limits, then :meth:`store`."""
        entry = self.entries.get((index, subindex)) or self.entry(index, subindex)
        if policy is not None:
            policy.check_write(entry, data)
        elif not entry.access.writable:
            raise SdoAbort(SdoAbortCode.READ_ONLY, f"0x{index:04X}:{subindex:02X}")
        self.store(entry, decode(entry, bytes(data)))

    def store(self, entry: Entry, value: Any) -> None:
        """A checked, decoded remote value: command, validators, store, write hooks, reactions, listeners."""
        # the index as one object (compiled: an int above 256 is boxed anew for every lookup of
        # the hook tables below) and the key as the one tuple object the table holds (Entry.key)
        index: Any = entry.index
        key: Any = entry.key
        values: dict[Any, Any] = self.values
        if index not in self.intercepted:    # a plain value (e.g. a PDO-mapped set-point)
            old = values[key]
            values[key] = value
            if old != value:
                listeners_of = self._listeners
                listeners = listeners_of.get(key) if listeners_of else None
                if listeners is not None:
                    for listener in listeners:
                        listener(key, value)
            return
        command = self._commands.get(index)
        if command is not None:
            command(entry, value)
            return
        validators = self._validators.get(index)
        if validators is not None:
            for validator in validators:
                validator(entry, value)
        old = values[key]
        values[key] = value
        hooks = self._write_hooks.get(index)
        if hooks is not None:
            try:
                for hook in hooks:
                    hook(index, entry.subindex, value)
            except Exception:
                values[key] = old
                raise
        reactions = self._reactions.get(index)
        if reactions is not None:
            for reaction in reactions:
                reaction(entry, value)
        if old != value:
            self._changed(key, value)
