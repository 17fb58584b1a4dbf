"""``gatewaylab run --web [PORT]``: the rig's buses, decoded, in a browser on 127.0.0.1.

The same :class:`~gatewaylab.canopen.monitor.BusMonitor` as ``gatewaylab monitor`` watches every
bus from inside the rig (a bus monitor hook: it never transmits or acknowledges). A small HTTP
server (standard library, its own thread) serves one page that updates itself by server-sent
events: the node table, the decoded log and a position plot of the drives.

Threads: the monitors run in the rig thread (they are called with every frame); the HTTP threads
only read what the monitors left under ``self._lock``, never protocol state.
"""

from __future__ import annotations

import json
import threading
from collections import deque
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

from ..bus import CanFrame, VirtualBus
from ..canopen.drive import Drive
from ..canopen.monitor import BusMonitor, MonitorEvent
from ..common.server_thread import ServerThread
from ..od.eds import import_eds

#: log lines kept for a page that connects later
_KEEP = 500


class RigWeb:
    """Monitors on every bus of a rig plus the HTTP server of the page."""

    def __init__(self, buses: dict[str, VirtualBus], drives: list[Drive], port: int = 0) -> None:
        self._lock = threading.Condition()
        self._events: deque[tuple[int, dict[str, Any]]] = deque(maxlen=_KEEP)
        self._seq = 0
        self.monitors: dict[str, BusMonitor] = {}
        for name, bus in buses.items():
            dictionaries = {d.node.node_id: import_eds(d.node.to_eds(), d.node.node_id)
                            for d in drives if d.bus is bus and d.node.node_id is not None}
            monitor = self.monitors[name] = BusMonitor(dictionaries, bus.bitrate, bus.data_bitrate)
            bus.add_monitor(self._hook(name, monitor))
        self._server = ThreadingHTTPServer(("127.0.0.1", port), self._handler())
        self._server.daemon_threads = True
        self._thread: ServerThread | None = None
        self.url = f"http://127.0.0.1:{self._server.server_address[1]}/"
        self.closing = False

    def _hook(self, bus_name: str, monitor: BusMonitor) -> Any:
        def on_frame(frame: CanFrame, t: float) -> None:
            with self._lock:     # the HTTP threads read the monitor's node table under the same lock
                events = monitor.feed(frame, t)
                if events:
                    self._publish(bus_name, events)
        return on_frame

    def _publish(self, bus_name: str, events: list[MonitorEvent]) -> None:
        with self._lock:
            for event in events:
                self._seq += 1
                self._events.append((self._seq, {"bus": bus_name, **event.to_json()}))
            self._lock.notify_all()

    def snapshot(self) -> dict[str, Any]:
        """The node tables and load figures of every bus (what /state and the page's table show)."""
        with self._lock:
            buses: dict[str, Any] = {}
            for name, m in self.monitors.items():
                buses[name] = {
                    "load": round(m.load_percent(), 2), "frames_per_s": round(m.frames_per_second(), 1),
                    "frames": m.frames,
                    "nodes": [{"node": v.node_id, "nmt": v.nmt, "heartbeat_t": v.heartbeat_t,
                               "cia402": v.cia402_state, "statusword": v.statusword, "mode": v.mode_name,
                               "position": v.position, "velocity": v.velocity, "emcy": v.emcy}
                              for v in sorted(m.nodes.values(), key=lambda v: v.node_id)]}
            return {"buses": buses, "log": [e for _, e in list(self._events)[-100:]]}

    def events_after(self, seq: int, timeout: float) -> tuple[int, list[dict[str, Any]]]:
        """Events newer than ``seq`` (waits up to ``timeout`` for one)."""
        with self._lock:
            if self._seq <= seq and not self.closing:
                self._lock.wait(timeout)
            fresh = [e for s, e in self._events if s > seq]
            return self._seq, fresh

    # -- HTTP ---------------------------------------------------------------------------------
    def _handler(self) -> type[BaseHTTPRequestHandler]:
        web = self

        class Handler(BaseHTTPRequestHandler):
            server_version = "gatewaylab-web"

            def log_message(self, format: str, *args: Any) -> None:
                """Quiet: the rig's log is for the rig."""

            def _send(self, status: int, body: bytes, ctype: str) -> None:
                self.send_response(status)
                self.send_header("Content-Type", ctype)
                self.send_header("Content-Length", str(len(body)))
                self.send_header("Cache-Control", "no-store")
                self.end_headers()
                self.wfile.write(body)

            def do_GET(self) -> None:
                path = self.path.split("?", 1)[0]
                if path == "/":
                    self._send(200, PAGE.encode(), "text/html; charset=utf-8")
                elif path == "/state":
                    self._send(200, json.dumps(web.snapshot()).encode(), "application/json")
                elif path == "/events":
                    self._stream()
                else:
                    self._send(404, b"not found\n", "text/plain")

            def _stream(self) -> None:
                """Server-sent events: 'log' for each decoded event, 'state' twice a second."""
                self.send_response(200)
                self.send_header("Content-Type", "text/event-stream")
                self.send_header("Cache-Control", "no-store")
                self.end_headers()
                seq = 0
                try:
                    for chunk in web._chunks(seq):
                        self.wfile.write(chunk)
                        self.wfile.flush()
                except (BrokenPipeError, ConnectionResetError):
                    return

        return Handler

    def _chunks(self, seq: int) -> Iterator[bytes]:
        first = True
        while not self.closing:
            seq, fresh = self.events_after(seq, 0.5)
            if first:
                fresh = fresh[-100:]
                first = False
            for event in fresh:
                yield f"event: log\ndata: {json.dumps(event)}\n\n".encode()
            yield f"event: state\ndata: {json.dumps(self.snapshot())}\n\n".encode()

    def start(self) -> str:
        """Serve in a daemon thread; returns the page's URL."""
        self._thread = ServerThread(self._server, "gatewaylab-web")
        self._thread.start()
        return self.url

    def stop(self) -> None:
        """Stop serving (open event streams end within half a second)."""
        with self._lock:
            self.closing = True
            self._lock.notify_all()
        if self._thread is not None:
            self._thread.stop()
            self._thread = None
        self._server.server_close()


PAGE = """<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>gatewaylab rig</title>
<style>
body { font-family: sans-serif; margin: 1em; }
table { border-collapse: collapse; margin-bottom: 1em; }
td, th { border: 1px solid #bbb; padding: 2px 8px; font-size: 90%; }
#log { font-family: monospace; font-size: 85%; height: 20em; overflow-y: scroll; border: 1px solid #bbb;
       white-space: pre; padding: 4px; }
canvas { border: 1px solid #bbb; }
</style></head>
<body>
<h1>gatewaylab rig</h1>
<div id="buses">waiting for the rig...</div>
<h2>Position of the drives</h2>
<canvas id="plot" width="900" height="220"></canvas>
<h2>Decoded log</h2>
<div id="log"></div>
<script>
const history = {};
function esc(s) { return String(s == null ? "" : s).replace(/[&<>"]/g,
  c => ({"&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;"}[c])); }
function hex(v) { return v == null ? "" : "0x" + v.toString(16).toUpperCase().padStart(4, "0"); }
function showState(state) {
  let html = "";
  for (const [name, bus] of Object.entries(state.buses)) {
    html += `<h2>bus ${esc(name)}: load ${bus.load.toFixed(1)} %, ${bus.frames_per_s.toFixed(0)} frames/s,
      ${bus.frames} frames</h2><table><tr><th>node</th><th>NMT</th><th>CiA 402</th><th>statusword</th>
      <th>mode</th><th>position</th><th>velocity</th><th>last EMCY</th></tr>`;
    for (const n of bus.nodes) {
      html += `<tr id="node-${esc(name)}-${n.node}"><td>${n.node}</td><td class="nmt">${esc(n.nmt)}</td>
        <td>${esc(n.cia402)}</td><td>${hex(n.statusword)}</td><td>${esc(n.mode)}</td>
        <td>${esc(n.position)}</td><td>${esc(n.velocity)}</td><td>${esc(n.emcy)}</td></tr>`;
      if (n.position != null) {
        const h = history[name + "/" + n.node] = history[name + "/" + n.node] || [];
        h.push(n.position); if (h.length > 300) h.shift();
      }
    }
    html += "</table>";
  }
  document.getElementById("buses").innerHTML = html;
  draw();
}
function draw() {
  const c = document.getElementById("plot"), g = c.getContext("2d");
  g.clearRect(0, 0, c.width, c.height);
  const series = Object.entries(history), colors = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd"];
  let lo = Infinity, hi = -Infinity;
  for (const [, h] of series) for (const v of h) { lo = Math.min(lo, v); hi = Math.max(hi, v); }
  if (!isFinite(lo)) return;
  if (hi === lo) { hi += 1; lo -= 1; }
  series.forEach(([key, h], i) => {
    g.strokeStyle = colors[i % colors.length]; g.beginPath();
    h.forEach((v, x) => { const y = c.height - 10 - (v - lo) / (hi - lo) * (c.height - 20);
      x === 0 ? g.moveTo(x * 3, y) : g.lineTo(x * 3, y); });
    g.stroke(); g.fillStyle = g.strokeStyle; g.fillText(key, 5, 12 + 12 * i);
  });
}
const log = document.getElementById("log");
const source = new EventSource("/events");
source.addEventListener("state", e => showState(JSON.parse(e.data)));
source.addEventListener("log", e => {
  const ev = JSON.parse(e.data);
  const line = document.createElement("div");
  line.textContent = `${ev.t.toFixed(6)}  ${ev.bus}  ${ev.text}`;
  log.appendChild(line);
  while (log.childNodes.length > 500) log.removeChild(log.firstChild);
  log.scrollTop = log.scrollHeight;
});
</script>
</body></html>
"""
