"""The one veth-namespace kit of the wire tests (EtherCAT over a veth pair, pysoem/KickCAT in a namespace).

Every test package that puts a master on a veth pair uses these two (gatewaylab/ethercat/wire_netns.py):
``net_capable()`` says why a test must
skip (not Linux, no iproute2, no CAP_NET_ADMIN/CAP_NET_RAW, a master library missing) and
``veth_namespace()`` makes a namespace with the master's end of a fresh veth pair in it, and removes both
again, whatever the test did. Importable from every test folder (tests/ is on sys.path through
tests/conftest.py).
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import socketserver
import subprocess
import sys
import tempfile
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from kickcat_kit import JUDGED, WIRE_COUNTERS_ENV

from gatewaylab.common.ask import ask, endpoint_address
from gatewaylab.common.endpoint import EndpointKind, parse_endpoint
from gatewaylab.ethercat.wire_netns import net_unavailable, veth_namespace

__all__ = ["WIRE_COUNTERS_ENV", "JsonMaster", "check_reruns", "lost_allowed", "net_capable", "rig_counters_env",
           "rig_wire_stats", "run_fault", "serve_wire_counters", "veth_namespace", "veth_namespace_two"]


def net_capable(*modules: str) -> str | None:
    """None when this process may create namespaces and raw sockets (and can import ``modules``), else the
    reason to skip."""
    return net_unavailable(*modules)


def lost_allowed(cycles: int) -> int:
    """Lost frames a cyclic wire test tolerates (2 %, at least 1), counted and printed, never hidden.

    A lost cycle -- no reply within the master's default timeout: SOEM's EC_NOFRAME, a KickCAT timeout --
    is what a real line may do and every master handles; on this shared VM the emulator drops a frame it
    could only answer late (``[ethercat] max_residence_ms``) and the kernel itself can hold a veth frame
    for milliseconds (a vCPU not scheduled). A wrong answer -- a reply with a wrong working counter, wrong
    data, a wrong state -- is never tolerated. docs/decisions.md says why the line is drawn here.
    """
    return max(1, cycles // 50)


def check_reruns(reruns: list[str], wire: dict[str, int]) -> None:
    """A master's step run again after a lost frame (a KickCAT scan, a mailbox read) is allowed only when the
    machine lost the frame, never the emulator: printed with the wire's counters, and failing when the wire
    dropped a frame it held itself past ``max_residence_ms`` (``frames_dropped_late`` less
    ``frames_late_on_arrival``, the frames the kernel or the VM handed to the idle wire thread already late).

    A rerun that a late emulator caused would hide exactly the defect a master's test run must show; a rerun
    after the machine held a frame (a vCPU not scheduled: docs/decisions.md) is a lost frame, which a real line
    has too. KickCAT's own give-ups with every frame answered in time (its ``Socket::read``) count as the
    machine's: the wire then counts no late frame at all. The KickCAT drivers judge each failed attempt as it
    happens (tests/ethercat/kickcat_kit.py ``run_step``, through ``serve_wire_counters`` or
    ``rig_counters_env``): a rerun they cleared (``JUDGED``) is not judged again here by the late drops of the
    whole run (those of the cyclic phases are lost cycles, counted by the test); the others -- no counters
    reachable, a new master after a failed bring-up -- are."""
    own = wire.get("frames_dropped_late", 0) - wire.get("frames_late_on_arrival", 0)
    blind = [r for r in reruns if not JUDGED.search(r)]
    print(f"steps run again after a lost frame: {len(reruns)} ({len(blind)} not judged by the driver) {reruns}; "
          f"the wire: {wire}")
    if blind:
        assert own == 0, (f"the emulator held {own} frame(s) past max_residence_ms and the master ran "
                          f"{len(blind)} step(s) again without the wire's counters: {blind}; {wire}")


def rig_wire_stats(info: dict[str, Any]) -> dict[str, int]:
    """The wire's counters of a running rig (its ready file's ``info``), from the control request
    ``ethercat-states`` (what ``gatewaylab monitor`` polls)."""
    endpoint = parse_endpoint(str(info["control"]), bare_path=EndpointKind.UNIX)
    answer: dict[str, Any] = json.loads(ask(endpoint_address(endpoint), {"fault": "ethercat-states"}, 10.0))
    wire: dict[str, int] = answer.get("wire") or {}
    return wire


def rig_counters_env(info: dict[str, Any]) -> dict[str, str]:
    """The environment of a driver that reads a running rig's wire counters itself between the attempts of a
    step (tests/ethercat/kickcat_kit.py ``run_step``): the rig's control socket, a Unix path, is reachable from
    inside the namespace. Nothing added when the rig's control endpoint is TCP (not reachable from there)."""
    endpoint = parse_endpoint(str(info["control"]), bare_path=EndpointKind.UNIX)
    if endpoint.kind is not EndpointKind.UNIX:
        return dict(os.environ)
    return {**os.environ, WIRE_COUNTERS_ENV: endpoint.path}


@contextlib.contextmanager
def serve_wire_counters(stats: Callable[[], dict[str, int]]) -> Iterator[dict[str, str]]:
    """For a wire in the test process (``WireTransport.stats``): a Unix socket answering the control request
    ``ethercat-states`` as a rig does (``{"wire": stats()}``, one JSON line per connection); yields the
    environment of a driver that reads the counters through it (``rig_counters_env``)."""

    class Answer(socketserver.StreamRequestHandler):
        def handle(self) -> None:
            self.rfile.readline()
            self.wfile.write(json.dumps({"wire": stats()}).encode() + b"\n")

    folder = tempfile.mkdtemp(prefix="gl-wc-")
    # one request at a time in one thread: no thread per request competing with the wire thread
    server = socketserver.UnixStreamServer(os.path.join(folder, "wire.sock"), Answer)
    thread = threading.Thread(target=server.serve_forever, name="wire-counters", daemon=True)
    thread.start()
    try:
        yield {**os.environ, WIRE_COUNTERS_ENV: str(server.server_address)}
    finally:
        server.shutdown()
        server.server_close()
        thread.join(5)
        shutil.rmtree(folder, ignore_errors=True)


@contextlib.contextmanager
def veth_namespace_two(ns_prefix: str, if_prefix: str) -> Iterator[tuple[str, str, str, str, str]]:
    """Two veth pairs whose master ends share one fresh namespace (a master with two interfaces: cable
    redundancy): (namespace, emulator end A, master end A, emulator end B, master end B); the second pair is
    deleted on exit with the first (``veth_namespace``)."""
    with veth_namespace(ns_prefix, if_prefix) as (ns, emu_a, mst_a):
        emu_b, mst_b = emu_a[:-1] + "f", mst_a[:-1] + "n"   # names of the same length as the first pair's
        try:
            subprocess.run(["ip", "link", "add", emu_b, "type", "veth", "peer", "name", mst_b, "netns", ns],
                           check=True, capture_output=True, text=True)
            subprocess.run(["ip", "link", "set", emu_b, "up"], check=True, capture_output=True, text=True)
            subprocess.run(["ip", "netns", "exec", ns, "ip", "link", "set", mst_b, "up"], check=True,
                           capture_output=True, text=True)
            yield ns, emu_a, mst_a, emu_b, mst_b
        finally:
            subprocess.run(["ip", "link", "del", emu_b], check=False, capture_output=True)


def run_fault(ready_file: str | Path, *args: str, timeout: float = 60.0) -> dict[str, Any]:
    """``gatewaylab fault READY-FILE --json ARGS`` from another process, as a user types it; its JSON answer."""
    done = subprocess.run([sys.executable, "-m", "gatewaylab", "fault", str(ready_file), "--json", *args],
                          capture_output=True, text=True, timeout=timeout, check=False)
    assert done.returncode == 0, done.stderr
    answer: dict[str, Any] = json.loads(done.stdout)
    return answer


class JsonMaster:
    """A master driver script in a namespace that takes one JSON command per stdin line (``{"do": WHAT, ...}``)
    and answers each with one JSON line; ``{"do": "quit"}`` ends it."""

    def __init__(self, namespace: str, driver: Path, *args: str) -> None:
        self.proc = subprocess.Popen(["ip", "netns", "exec", namespace, sys.executable, str(driver), *args],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)

    def do(self, what: str, **args: Any) -> dict[str, Any]:
        """Send one command; its answer (an answer with ``failed`` fails the test)."""
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.write(json.dumps({"do": what, **args}) + "\n")
        self.proc.stdin.flush()
        text = self.proc.stdout.readline()
        assert text, f"the master ended: {self.proc.stderr.read() if self.proc.stderr else ''}"
        answer: dict[str, Any] = json.loads(text)
        assert "failed" not in answer, answer
        return answer

    def close(self) -> None:
        """Ask it to quit; killed when it does not within 20 s."""
        if self.proc.poll() is None:
            assert self.proc.stdin is not None
            self.proc.stdin.write('{"do": "quit"}\n')
            self.proc.stdin.flush()
            try:
                self.proc.wait(20)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
