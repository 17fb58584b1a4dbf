"""The ESI files of one rig build, each read and parsed once, and one dictionary built per device type.

A segment of 100 terminals names two ESI files 100 times (``[[device]] kind = "esi"`` sections, the
ENI's slaves, the ``[ethercat] esi`` folder scan). :class:`EsiFiles` reads and parses a file the first
time it is asked for, keyed by the file's resolved path, modification time and size (a file changed
during the build is read again), picks each device once, and builds each device's dictionary once:
every slave gets a copy of that dictionary's rows and values (:meth:`ObjectDictionary.copy`), its own
hooks, and its own identity. Nothing mutable is shared between slaves: the parsed tree and the
:class:`EsiDevice` are read-only after parsing, the template dictionary is never given out.

The rig build owns one (``rig.build_cache.part(EsiFiles)``); a new build reads every file again.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Callable
from dataclasses import replace
from functools import partial
from pathlib import Path

from gatewaylab.devices.esi.reader import EsiDevice, EsiError, apply_dictionary, esi_device, parse_esi
from gatewaylab.ethercat.description import DeviceDescription, add_pdo_checks, build_od
from gatewaylab.od import ObjectDictionary

__all__ = ["EsiFiles", "FileKey", "file_key"]

#: (resolved path, modification time in ns, size in bytes): one version of one file.
FileKey = tuple[str, int, int]


def file_key(path: Path) -> FileKey:
    """The key of the file's present version (an :class:`EsiError` naming it when it cannot be read)."""
    try:
        resolved = path.resolve()
        st = resolved.stat()
    except OSError as exc:
        raise EsiError(f"{path}: cannot read it ({exc.strerror or exc})") from None
    return str(resolved), st.st_mtime_ns, st.st_size


def _read(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except OSError as exc:
        raise EsiError(f"{path}: cannot read it ({exc.strerror or exc})") from None


class EsiFiles:
    """Parsed ESI files, their devices and one dictionary per device, for one rig build.

    ``read`` reads a file's bytes (tests count with it); ``reads``, ``parses`` and ``dictionaries`` count
    what was done, so a test sees that 100 slaves of one type read their file once."""

    def __init__(self, read: Callable[[Path], bytes] = _read) -> None:
        self._read = read
        #: files read, XML trees parsed, template dictionaries built
        self.reads = 0
        self.parses = 0
        self.dictionaries = 0
        self._texts: dict[FileKey, bytes] = {}
        self._roots: dict[FileKey, ET.Element] = {}
        self._devices: dict[tuple[FileKey, str, str | None, int | None, int | None], EsiDevice] = {}
        #: id(device) -> (the device, kept alive so the id stays its own; its dictionary)
        self._templates: dict[int, tuple[EsiDevice, ObjectDictionary]] = {}
        #: devices whose notes were said (kept alive, as above)
        self._said: dict[int, EsiDevice] = {}

    def text(self, path: Path) -> tuple[FileKey, bytes]:
        """The file's key and bytes, read once per version."""
        key = file_key(path)
        text = self._texts.get(key)
        if text is None:
            text = self._texts[key] = self._read(path)
            self.reads += 1
        return key, text

    def root(self, path: Path, source: str) -> tuple[FileKey, ET.Element]:
        """The file's key and its parsed tree (namespaces dropped; any root element), parsed once per version;
        ``source`` names the file in errors."""
        key, text = self.text(path)
        root = self._roots.get(key)
        if root is None:
            root = self._roots[key] = parse_esi(text, source)
            self.parses += 1
        return key, root

    def device(self, path: Path, source: str, type_name: str | None = None, product_code: int | None = None,
               revision: int | None = None) -> EsiDevice:
        """One device of the file (as :func:`~gatewaylab.devices.esi.reader.read_esi` picks it), read once."""
        key, root = self.root(path, source)
        wanted = (key, source, type_name, product_code, revision)
        found = self._devices.get(wanted)
        if found is None:
            found = self._devices[wanted] = esi_device(root, source, type_name, product_code, revision)
        return found

    def dictionary(self, device: EsiDevice, desc: DeviceDescription,
                   extend: Callable[[ObjectDictionary], None] | None = None) -> ObjectDictionary:
        """A dictionary of its own for one slave of ``device`` running ``desc`` (``esi_description(device,
        ...)``, the same objects): the rows and values of the device's dictionary, built once, the PDO checks
        ``build_od`` adds, then ``extend`` (what differs per slave: the serial number, a revision)."""
        held = self._templates.get(id(device))
        if held is None or held[0] is not device:
            # what esi_description(device) builds (no serial: 0x1018:04 as the ESI says; no SII: not in it)
            template = build_od(replace(device.desc, serial=0, extend_od=partial(apply_dictionary, device=device)))
            held = self._templates[id(device)] = (device, template)
            self.dictionaries += 1
        od = held[1].copy()
        add_pdo_checks(od, desc)
        if extend is not None:
            extend(od)
        return od

    def unsaid_notes(self, device: EsiDevice) -> tuple[str, ...]:
        """The device's notes (what its slaves do differently from the file) the first time it is asked for in
        this build, then nothing: 50 slaves of one type say them once."""
        if self._said.get(id(device)) is device:
            return ()
        self._said[id(device)] = device
        return device.notes
