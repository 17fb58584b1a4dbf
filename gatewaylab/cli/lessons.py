"""Short scripted CANopen scenarios that explain themselves (``gatewaylab lesson NAME``).

Each lesson builds a small network on a simulated clock (so its output is the same on every run),
lets a master do a few things step by step and tells, for every step: why the master does it,
every frame that goes over the bus (who sent it, to whom, its bytes and meaning from
:func:`.explain.explain`), and what changed in the nodes (NMT state, LSS state, CiA 402 state,
node-ID, the dictionary entries the lesson watches). It ends with a sequence diagram of the whole
conversation, as text or as mermaid (for docs/teaching/).
"""

from __future__ import annotations

import tempfile
import textwrap
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gatewaylab.bus import CanFrame, VirtualBus
from gatewaylab.canopen.explain import explain
from gatewaylab.canopen.lss import LssMaster, LssState
from gatewaylab.canopen.monitor import FastscanNarrator
from gatewaylab.canopen.nmt import NmtCommand, encode_nmt
from gatewaylab.canopen.sdo_client import SdoClient
from gatewaylab.common.clock import SimulatedClock
from gatewaylab.devices.canopen_drive.device import Drive

__all__ = ["LESSONS", "Arrow", "Classroom", "Say", "run_lesson"]


Say = Callable[[str], None]
#: The master's own COB-IDs (CiA 301 predefined connection set, CiA 305): what it sends.
_LSS_PARTS = ("vendor", "product", "revision", "serial")
#: Watched objects shown in hex (codes and bit fields), besides the PDO parameters 0x1400-0x1BFF.
_HEX_OBJECTS = (0x1001, 0x603F, 0x6040, 0x6041)
_START_2 = encode_nmt(NmtCommand.START_REMOTE_NODE, 2)


@dataclass(frozen=True, slots=True)
class Arrow:
    """One frame of the conversation, for the sequence diagram."""

    t: float
    sender: str
    receiver: str
    text: str


@dataclass
class Classroom:
    """A 1 Mbit/s bus on a simulated clock, a master (SDO client, LSS master, NMT) and drives."""

    say: Say
    clock: SimulatedClock = field(default_factory=SimulatedClock)
    drives: dict[str, Drive] = field(default_factory=dict)
    arrows: list[Arrow] = field(default_factory=list)
    watched: tuple[tuple[int, int], ...] = ()
    quiet_lss: bool = False

    def __post_init__(self) -> None:
        self.bus = VirtualBus(self.clock, "can0", bitrate=1_000_000)
        self.master = self.bus.attach("master")
        #: COB-IDs of the frames the master queued and the bus has not carried yet (its FIFO)
        self._queued: deque[int] = deque()
        self.sdo = SdoClient(self.clock, self.send)
        self.lss = LssMaster(self.clock, self.send)
        self.master.on_frame = self._master_hears
        #: the drives' non-volatile memory (LSS store, parameters) for the length of the lesson
        self._store = tempfile.TemporaryDirectory(prefix="gatewaylab-lesson-")
        self.bus.add_monitor(self._on_frame)
        self._fastscan = FastscanNarrator(self._fastscan_bit)
        self._compressed = 0

    # -- cast -----------------------------------------------------------------------------------
    def add_drive(self, name: str, node_id: int | None, serial: int) -> Drive:
        """Put a drive on the lesson's bus (its parameters stored in the classroom's folder) and return it."""
        store = Path(self._store.name) / f"{name.replace(' ', '-')}.params.json"
        drive = Drive(self.clock, self.bus, node_id, serial, name=name, store_path=store)
        self.drives[name] = drive
        return drive

    def _master_hears(self, frame: CanFrame, t: float) -> None:
        self.sdo.on_frame(frame, t)
        self.lss.on_frame(frame, t)

    def _who(self, frame: CanFrame, from_master: bool) -> tuple[str, str]:
        """(sender, receiver) of a frame, from its COB-ID (CiA 301 predefined connection set)."""
        cid = frame.can_id
        by_id = {d.node.node_id: name for name, d in self.drives.items() if d.node.node_id is not None}
        if from_master:
            if cid == 0x000 and len(frame.data) == 2 and frame.data[1]:
                return "master", by_id.get(frame.data[1], f"node {frame.data[1]}")
            if 0x601 <= cid <= 0x67F or 0x201 <= cid <= 0x57F:
                return "master", by_id.get(cid & 0x7F, f"node {cid & 0x7F}")
            return "master", next(iter(self.drives)) if len(self.drives) == 1 else "all"
        node = cid & 0x7F
        if cid == 0x7E4:
            unconfigured = [n for n, d in self.drives.items() if d.node.node_id is None]
            return (unconfigured[0] if len(unconfigured) == 1 else "LSS slave"), "master"
        return by_id.get(node, f"node {node}"), "master"

    def _on_frame(self, frame: CanFrame, t: float) -> None:
        from_master = bool(self._queued) and self._queued[0] == frame.can_id
        if from_master:
            self._queued.popleft()
        sender, receiver = self._who(frame, from_master)
        text = explain(frame)
        if frame.can_id == 0x7E5:
            self._fastscan.request(frame.data)
        self.arrows.append(Arrow(t, sender, receiver, text))
        if self.quiet_lss and frame.can_id in (0x7E4, 0x7E5):
            self._compressed += 1
        else:
            self.say(f"  {t * 1000:9.3f} ms  {sender:>8} -> {receiver:<8} {frame.can_id:03X} "
                     f"{frame.data.hex(' ').upper():<23}  {text}")
        if frame.can_id == 0x7E4 and frame.data[:1] == b"\x4f":
            self._fastscan.answer()

    def _fastscan_bit(self, sub: int, bit: int, value: int) -> None:
        if not self.quiet_lss or bit in (31, 0):
            self.say(f"  {'':9}     Fastscan: bit {bit:2} of the {_LSS_PARTS[sub]} is {value}"
                     + (" (no answer)" if value else " (a slave answered)"))

    # -- doing ----------------------------------------------------------------------------------
    def _snapshot(self) -> dict[str, dict[str, Any]]:
        out: dict[str, dict[str, Any]] = {}
        for name, d in self.drives.items():
            node = d.node
            view: dict[str, Any] = {
                "node-ID": "unconfigured" if node.node_id is None else node.node_id,
                "NMT state": node.nmt_state.label,
                "LSS state": d.lss.state.name.lower(),
                "CiA 402 state": d.state.value.lower(),
            }
            for index, sub in self.watched:
                entry = node.od.entries.get((index, sub))
                if entry is not None:
                    value = node.od.values[(index, sub)]
                    hexa = isinstance(value, int) and (0x1400 <= index <= 0x1BFF or index in _HEX_OBJECTS)
                    view[f"0x{index:04X}:{sub:02X} {entry.name}"] = (
                        f"0x{value:0{2 * (entry.size or 4)}X}" if hexa else value)
            out[name] = view
        return out

    def step(self, title: str, why: str, action: Callable[[], None], settle: float = 0.01,
             sample_lss: bool = False) -> None:
        """Run one step: tell why, do ``action`` (frames the master sends), let the bus settle, report
        every frame and every change in the nodes (``sample_lss``: a Fastscan's 130 request/answer
        pairs are told as a sample of its bisection steps)."""
        self.quiet_lss = sample_lss
        self.say("")
        self.say(f"== {title}")
        for i, line in enumerate(textwrap.wrap(why, 96)):
            self.say(("   why: " if i == 0 else "        ") + line)
        before = self._snapshot()
        self._compressed = 0
        with self.clock.lock:
            action()
            self.clock.run_while(lambda: self.sdo_busy() or self.lss.busy or self.bus.busy, max_events=2_000_000)
            self.clock.advance(settle)
        self._fastscan.flush()
        if self._compressed:
            self.say(f"  {'':9}     ({self._compressed} LSS frames in all; the lines above are a sample of the "
                     "bisection: the first and last bit of each part)")
        after = self._snapshot()
        changes = [f"     {name}: {key}: {before[name].get(key)} -> {value}"
                   for name, view in after.items() for key, value in view.items() if before[name].get(key) != value]
        self.say("   changed:" + ("" if changes else " nothing"))
        for line in changes:
            self.say(line)

    def close(self) -> None:
        """Forget the drives' stored memory."""
        self._store.cleanup()

    def sdo_busy(self) -> bool:
        """Whether an SDO transfer to one of the drives is still running (a lesson waits for it)."""
        return any(self.sdo.busy(d.node.node_id) for d in self.drives.values() if d.node.node_id is not None)

    def send(self, frame: CanFrame) -> None:
        """Every frame of the master (NMT, SYNC, and those of its SDO client and LSS master)."""
        self._queued.append(frame.can_id)
        self.master.send(frame)

    def start(self) -> None:
        """Power on every drive (boot-up into Pre-operational, or LSS waiting without a node-ID)."""
        def power() -> None:
            for d in self.drives.values():
                d.start()
        self.step("Power on", "each drive boots: with a node-ID it sends its boot-up message and waits in "
                  "Pre-operational (CiA 301 7.3.2); without one it waits for an LSS master (CiA 305)", power)

    # -- the end --------------------------------------------------------------------------------
    def participants(self) -> list[str]:
        """The lanes of the sequence diagram: the master first, then every node in the order it first appeared."""
        seen = ["master"]
        for a in self.arrows:
            for who in (a.sender, a.receiver):
                if who not in seen:
                    seen.append(who)
        return seen

    def diagram(self, limit: int = 40) -> list[str]:
        """The conversation as a text sequence diagram (long LSS runs shortened)."""
        cols = self.participants()
        width = 14
        pos = {name: 2 + i * width for i, name in enumerate(cols)}
        total = 2 + len(cols) * width
        lines = ["".join(f"{name:<{width}}" for name in cols).rstrip()]

        def bar() -> list[str]:
            row = [" "] * total
            for p in pos.values():
                row[p] = "|"
            return row
        arrows = self.arrows
        if len(arrows) > limit:
            arrows = [*arrows[:limit // 2], Arrow(0, "", "", f"... {len(self.arrows) - limit} more ..."),
                      *arrows[-limit // 2:]]
        for a in arrows:
            row = bar()
            if not a.sender:
                lines.append("".join(row).rstrip() + "   " + a.text)
                continue
            s, r = pos[a.sender], pos[a.receiver]
            lo, hi = min(s, r), max(s, r)
            for i in range(lo + 1, hi):
                row[i] = "-"
            if r > s:
                row[hi - 1] = ">"
            else:
                row[lo + 1] = "<"
            lines.append("".join(row).rstrip() + "   " + a.text)
        return lines

    def mermaid(self, limit: int = 40) -> list[str]:
        """The same diagram in mermaid (docs/teaching/)."""
        out = ["sequenceDiagram"]
        out += [f"    participant {name.replace(' ', '_')} as {name}" for name in self.participants()]
        arrows = self.arrows if len(self.arrows) <= limit else [*self.arrows[:limit // 2], *self.arrows[-limit // 2:]]
        for i, a in enumerate(arrows):
            if len(self.arrows) > limit and i == limit // 2:
                out.append(f"    Note over master: ... {len(self.arrows) - limit} more frames ...")
            text = a.text.replace(";", ",").replace("#", "")
            out.append(f"    {a.sender.replace(' ', '_')}->>{a.receiver.replace(' ', '_')}: {text}")
        return out


# -- the lessons ------------------------------------------------------------------------------------
def _nmt(room: Classroom) -> None:
    room.add_drive("drive 2", 2, 0x1002)
    room.watched = ((0x1017, 0),)
    room.start()
    room.step("Ask for heartbeats", "the master writes 0x1017 (producer heartbeat time, ms) so the node "
              "reports its NMT state every 100 ms: that is how a master notices a node that vanished",
              lambda: room.sdo.download(2, 0x1017, 0, (100).to_bytes(2, "little"), _ignore), settle=0.15)
    room.step("Start the node", "NMT 'start remote node' (COB-ID 0, command 0x01, node 2): "
              "in Operational the node also exchanges PDOs", lambda: room.send(_START_2),
              settle=0.12)
    room.step("Stop it", "NMT 'stop' (0x02): only NMT and heartbeats are served in Stopped",
              lambda: room.send(encode_nmt(NmtCommand.STOP_REMOTE_NODE, 2)), settle=0.12)
    room.step("Reset communication", "NMT 0x82: communication parameters (0x1000-0x1FFF) back to their "
              "stored values; the node boots again (boot-up message) into Pre-operational",
              lambda: room.send(encode_nmt(NmtCommand.RESET_COMMUNICATION, 2)), settle=0.05)


def _ignore(result: object) -> None:
    """Lessons report results through the frames and the changes, not through callbacks."""


def _sdo(room: Classroom) -> None:
    room.add_drive("drive 2", 2, 0x1002)
    room.watched = ((0x6060, 0),)
    room.start()
    room.step("Read the device type (expedited upload)", "0x1000 fits in 4 bytes, so the answer carries "
              "the value itself: one request, one response (CiA 301 7.2.4.3.6)",
              lambda: room.sdo.upload(2, 0x1000, 0, _ignore))
    room.step("Read the device name (segmented upload)", "0x1008 is longer than 4 bytes: the response "
              "announces the size, then the client asks for 7-byte segments with a toggle bit",
              lambda: room.sdo.upload(2, 0x1008, 0, _ignore))
    room.step("Write the mode of operation (expedited download)", "0x6060 = 1 selects profile position "
              "mode; the server confirms with 0x60 and the dictionary entry changes",
              lambda: room.sdo.download(2, 0x6060, 0, bytes((1,)), _ignore))
    room.step("Read an object that does not exist", "the server answers with an abort: command 0x80 "
              "and a 32-bit reason code (CiA 301 table 22)", lambda: room.sdo.upload(2, 0x1234, 0, _ignore))


def _pdo(room: Classroom) -> None:
    room.add_drive("drive 2", 2, 0x1002)
    room.watched = ((0x1801, 1), (0x1801, 2), (0x1A01, 0), (0x1A01, 1))
    room.start()

    def write(index: int, sub: int, value: int, size: int) -> Callable[[], None]:
        return lambda: room.sdo.download(2, index, sub, value.to_bytes(size, "little"), _ignore)
    room.step("Disable TPDO2", "a PDO is remapped while it is invalid: set bit 31 of its COB-ID "
              "(0x1801:01), CiA 301 7.5.2.36", write(0x1801, 1, 0x80000282, 4))
    room.step("Clear its mapping", "sub-index 0 of 0x1A01 = 0 before the entries change",
              write(0x1A01, 0, 0, 1))
    room.step("Map 0x6064 (position actual value, 32 bits)", "a mapping entry is index << 16 | sub << 8 "
              "| length in bits: 0x60640020", write(0x1A01, 1, 0x60640020, 4))
    room.step("One object mapped", "sub-index 0 = number of mapped objects", write(0x1A01, 0, 1, 1))
    room.step("Send it on every SYNC", "transmission type 1 = synchronous, every SYNC (0x1801:02)",
              write(0x1801, 2, 1, 1))
    room.step("Enable TPDO2 again", "clear bit 31: COB-ID 0x282 = 0x280 + node-ID",
              write(0x1801, 1, 0x282, 4))
    room.step("Start the node", "PDOs flow only in Operational", lambda: room.send(_START_2))
    room.step("SYNC", "the master's SYNC (COB-ID 0x80) makes the node send TPDO2 with the position",
              lambda: room.send(CanFrame(0x080, b"")))


def _sync(room: Classroom) -> None:
    room.add_drive("drive 2", 2, 0x1002)
    room.add_drive("drive 3", 3, 0x1003)
    room.watched = ((0x1800, 2),)
    room.start()

    def synchronous() -> None:
        for node in (2, 3):
            room.sdo.download(node, 0x1800, 2, b"\x01", _ignore)
    room.step("Make TPDO1 synchronous", "transmission type 1 (0x1800:02): send TPDO1 after every SYNC "
              "instead of on every change (CiA 301 7.5.2.35)", synchronous)
    room.step("Start all nodes", "NMT to node 0 addresses every node; PDOs flow in Operational",
              lambda: room.send(encode_nmt(NmtCommand.START_REMOTE_NODE, 0)))
    for n in (1, 2):
        room.step(f"SYNC {n}", "one SYNC (COB-ID 0x80, highest priority after NMT) makes every node sample "
                  "its inputs and send its synchronous TPDOs at the same instant; their COB-IDs decide "
                  "the order on the bus", lambda: room.send(CanFrame(0x080, b"")))


def _emcy(room: Classroom) -> None:
    drive = room.add_drive("drive 2", 2, 0x1002)
    room.watched = ((0x1001, 0), (0x603F, 0))
    room.start()
    room.step("Start the node", "EMCY messages are sent in Pre-operational and Operational (not Stopped)",
              lambda: room.send(_START_2))
    room.step("A following error", "the drive's position lags its demand by more than the window "
              "(0x6065): it reports EMCY 0x8611 with error register 0x1001 and enters Fault (CiA 402)",
              lambda: drive.fault(0x8611, 0x20), settle=0.05)
    room.step("Read the error history", "0x1003:01 keeps the last error code (CiA 301 7.5.2.4)",
              lambda: room.sdo.upload(2, 0x1003, 1, _ignore))
    room.step("Fault reset", "controlword bit 7 (0x80) leaves Fault; the drive sends EMCY 0x0000 "
              "'error reset' with the error register that remains",
              lambda: room.sdo.download(2, 0x6040, 0, (0x80).to_bytes(2, "little"), _ignore), settle=0.05)


def _lss(room: Classroom) -> None:
    room.add_drive("new drive", None, 0x00C0FFEE)
    room.quiet_lss = True
    room.start()
    room.step("Find the unconfigured drive (Fastscan)", "a drive without node-ID cannot be addressed "
              "by SDO; Fastscan finds its 128-bit LSS address (0x1018) bit by bit: 'is there a slave "
              "whose bits above b match?' -- an answer means bit b is 0 (CiA 305 8.3.5)",
              lambda: room.lss.fast_scan(_ignore), sample_lss=True)
    room.step("Give it node-ID 4", "configure node-ID goes to the one slave in LSS configuration state",
              lambda: room.lss.configure_node_id(4, _ignore))
    room.step("Store it", "so the drive keeps node-ID 4 after a power cycle",
              lambda: room.lss.store_configuration(_ignore))
    room.step("Back to waiting state", "leaving configuration state makes the pending node-ID active: "
              "the drive boots as node 4", lambda: room.lss.switch_state_global(LssState.WAITING), settle=0.05)


def _cia402(room: Classroom) -> None:
    room.add_drive("drive 2", 2, 0x1002)
    room.watched = ((0x6041, 0), (0x6060, 0), (0x6064, 0))
    room.start()

    def cw(value: int) -> Callable[[], None]:
        return lambda: room.sdo.download(2, 0x6040, 0, value.to_bytes(2, "little"), _ignore)
    room.step("Profile position mode", "0x6060 = 1. The node stays in Pre-operational: SDO works there and no "
              "PDOs flow, so the bus shows only the commands and their answers (a real control loop uses "
              "PDOs in Operational)", lambda: room.sdo.download(2, 0x6060, 0, b"\x01", _ignore))
    room.step("Shutdown (0x06)", "Switch on disabled -> Ready to switch on (CiA 402 transition 2)", cw(0x06))
    room.step("Switch on (0x07)", "-> Switched on (transition 3)", cw(0x07))
    room.step("Enable operation (0x0F)", "-> Operation enabled (transition 4): the motor holds its position",
              cw(0x0F))
    def move() -> None:
        room.sdo.download(2, 0x607A, 0, (1000).to_bytes(4, "little", signed=True), _ignore)
        room.sdo.download(2, 0x6040, 0, (0x1F).to_bytes(2, "little"), _ignore)
    room.step("Target 1000 and new set-point (0x1F)", "0x607A = 1000, then controlword bit 4 starts the move",
              move, settle=0.5)
    room.step("Where is it?", "0x6064 position actual value, read after the move (bit 10 of the statusword, "
              "target reached, is set again)", lambda: room.sdo.upload(2, 0x6064, 0, _ignore))
    room.step("Disable voltage (0x00)", "-> Switch on disabled (transition 9)", cw(0x00))


LESSONS: dict[str, tuple[str, Callable[[Classroom], None]]] = {
    "nmt": ("NMT: boot-up, heartbeat, start, stop, reset", _nmt),
    "sdo": ("SDO: expedited and segmented transfers, an abort", _sdo),
    "pdo": ("PDO: map an object into a TPDO and watch it on SYNC", _pdo),
    "sync": ("SYNC: synchronous TPDOs of two drives", _sync),
    "emcy": ("EMCY: a drive fault, the error history, fault reset", _emcy),
    "lss": ("LSS: find an unconfigured drive with Fastscan and give it a node-ID", _lss),
    "cia402": ("CiA 402: the power state machine to Operation enabled and a move", _cia402),
}


def run_lesson(name: str, say: Say, mermaid: bool = False) -> Classroom:
    """Run lesson ``name``, telling everything through ``say``; ends with its sequence diagram."""
    title, script = LESSONS[name]
    room = Classroom(say)
    say(f"Lesson {name}: {title}")
    script(room)
    say("")
    say("Sequence diagram:" if not mermaid else "Sequence diagram (mermaid):")
    for line in (room.mermaid() if mermaid else room.diagram()):
        say("  " + line if not mermaid else line)
    for drive in room.drives.values():
        drive.stop()
    room.close()
    return room
