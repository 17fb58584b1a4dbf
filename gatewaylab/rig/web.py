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

from gatewaylab.bus import CanFrame, VirtualBus
from gatewaylab.bus.controller import BusEvent, Controller, ErrorFrameEvent, StateChangeEvent
from gatewaylab.bus.errorframe import bus_error, state_change
from gatewaylab.canopen.monitor import BusMonitor, ControllerWatch, MonitorEvent, SignalSource
from gatewaylab.common.server_thread import ServerThread
from gatewaylab.devices.canopen_drive.device import Drive
from gatewaylab.od.eds import import_eds

__all__ = ["PAGE", "WATCH_PERIOD", "RigWeb"]


#: log lines kept for a page that connects later
_KEEP = 500
#: how often the page looks at the controllers of each bus and at silent nodes (seconds)
WATCH_PERIOD = 0.1


class RigWeb:
    """Monitors on every bus of a rig plus the HTTP server of the page."""

    def __init__(self, buses: dict[str, VirtualBus], drives: list[Drive], port: int = 0,
                 signals: SignalSource | None = None) -> None:
        self._lock = threading.Condition()
        self._events: deque[tuple[int, dict[str, Any]]] = deque(maxlen=_KEEP)
        self._seq = 0
        self.monitors: dict[str, BusMonitor] = {}
        self.buses = dict(buses)
        #: per bus: the page's own listen-only controller (it sees error frames) and the controller watch
        self._listeners: dict[str, Controller] = {}
        self._watches: dict[str, ControllerWatch] = {}
        self.controllers: dict[str, dict[str, dict[str, Any]]] = {}
        for name, bus in buses.items():
            dictionaries = {d.node.node_id: import_eds(d.node.to_eds(), d.node.node_id)
                            for d in drives if d.bus is bus and d.node.node_id is not None}
            monitor = self.monitors[name] = BusMonitor(dictionaries, bus.bitrate, bus.data_bitrate, signals=signals)
            bus.add_monitor(self._hook(name, monitor))
            self._listeners[name] = bus.attach("gatewaylab-web", listen_only=True,
                                               on_event=self._event_hook(name, monitor))
            self._watches[name] = ControllerWatch()
        clock = next(iter(buses.values())).clock if buses else None
        self._timer = clock.call_every(WATCH_PERIOD, self._watch) if clock is not None else None
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

    def _event_hook(self, bus_name: str, monitor: BusMonitor) -> Any:
        """Error frames and state changes of the page's listen-only controller, as SocketCAN reports them."""
        def on_event(ev: BusEvent) -> None:
            ctrl = self._listeners.get(bus_name)
            if isinstance(ev, ErrorFrameEvent) and ctrl is not None:
                err = bus_error(ev.kind.value, ev.transmitter, ctrl.tec, ctrl.rec)
            elif isinstance(ev, StateChangeEvent):
                err = state_change(ev.old.value, ev.new.value, ev.tec, ev.rec)
            else:
                return
            with self._lock:
                self._publish(bus_name, monitor.feed_error(err, ev.timestamp))
        return on_event

    def _watch(self) -> None:
        """In the rig thread, every WATCH_PERIOD: the controllers of each bus (bus-off, recovery, unplugged,
        joined, left) and the nodes whose heartbeat stopped."""
        for name, bus in self.buses.items():
            mine = self._listeners.get(name)
            states = {c.name: {"state": c.state.value, "tec": c.tec, "rec": c.rec, "connected": c.connected,
                               "bus_offs": c.stats.bus_offs}
                      for c in bus.controllers if c is not mine and not c.listen_only and not c.synthetic}
            events = self._watches[name].update(states, bus.clock.now())
            with self._lock:
                events += self.monitors[name].tick(bus.clock.now())
                self.controllers[name] = states
                if events:
                    self._publish(name, events)

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
                    "frames": m.frames, "error_frames": m.error_frames,
                    "controllers": self.controllers.get(name, {}),
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
        if self._timer is not None:
            clock = next(iter(self.buses.values())).clock
            with clock.lock:
                self._timer.cancel()
                for name, ctrl in self._listeners.items():
                    self.buses[name].detach(ctrl)
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
#scope { border: 1px solid #bbb; background: #fff; }
#scope .grid { stroke: #e4e4e4; } #scope text { font-size: 11px; fill: #333; }
#legend span { margin-right: 1.5em; } #legend i { display: inline-block; width: 1.5em; height: 3px;
  vertical-align: middle; margin-right: 0.3em; }
</style></head>
<body>
<h1>gatewaylab rig</h1>
<div id="buses">waiting for the rig...</div>
<h2>Position of the drives</h2>
<div id="scope-controls">window <select id="window"><option value="10">10 s</option>
<option value="30" selected>30 s</option><option value="60">60 s</option><option value="300">5 min</option></select>
<label><input type="checkbox" id="pause"> pause</label>
<span id="scope-note">time: seconds since the rig started (the bus clock)</span></div>
<svg id="scope" width="900" height="260" xmlns="http://www.w3.org/2000/svg"></svg>
<div id="legend"></div>
<h2>Decoded log</h2>
<div id="filters">hide: <label><input type="checkbox" id="hide-heartbeat" checked> heartbeats</label>
<label><input type="checkbox" id="hide-pdo"> PDOs</label> <label><input type="checkbox" id="hide-sync"> SYNC</label>
&nbsp; only lines containing: <input id="grep" size="20"></div>
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
      ${bus.frames} frames, ${bus.error_frames} error frames</h2>`;
    const ctrls = Object.entries(bus.controllers || {});
    if (ctrls.length) {
      html += `<table class="controllers"><tr><th>controller</th><th>state</th><th>TEC</th><th>REC</th>
        <th>cable</th><th>bus-offs</th></tr>`;
      for (const [cname, c] of ctrls)
        html += `<tr id="ctrl-${esc(name)}-${esc(cname)}"><td>${esc(cname)}</td><td class="state">${esc(c.state)}</td>
          <td>${c.tec}</td><td>${c.rec}</td><td>${c.connected ? "plugged" : "unplugged"}</td>
          <td>${c.bus_offs}</td></tr>`;
      html += "</table>";
    }
    html += `<table><tr><th>node</th><th>NMT</th><th>CiA 402</th><th>statusword</th>
      <th>mode</th><th>position</th><th>velocity</th><th>last EMCY</th></tr>`;
    for (const n of bus.nodes) {
      html += `<tr id="node-${esc(name)}-${n.node}"><td>${n.node}</td><td class="nmt">${esc(n.nmt)}</td>
        <td>${esc(n.cia402)}</td><td>${hex(n.statusword)}</td><td>${esc(n.mode)}</td>
        <td>${esc(n.position)}</td><td>${esc(n.velocity)}</td><td>${esc(n.emcy)}</td></tr>`;
    }
    html += "</table>";
  }
  document.getElementById("buses").innerHTML = html;
  draw();
}
const COLORS = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b"];
function record(ev) {
  // every position a PDO or an SDO read carries, at its bus time (CiA 402 0x6064)
  const v = ev.values ? ev.values["0x6064:00"] : (ev.index === 0x6064 ? ev.value : undefined);
  if (typeof v !== "number") return;
  const key = ev.bus + " node " + ev.node, h = history[key] = history[key] || [];
  h.push([ev.t, v]);
  while (h.length > 20000) h.shift();
}
function ticks(lo, hi, n) {
  const raw = (hi - lo) / n, mag = Math.pow(10, Math.floor(Math.log10(raw)));
  const step = [1, 2, 5, 10].map(m => m * mag).find(s => s >= raw);
  const out = [];
  for (let v = Math.ceil(lo / step) * step; v <= hi + 1e-9; v += step) out.push(+v.toPrecision(12));
  return out;
}
function draw() {
  if (document.getElementById("pause").checked) return;
  const svg = document.getElementById("scope"), W = +svg.getAttribute("width"), H = +svg.getAttribute("height");
  const L = 70, R = 10, T = 10, B = 35, win = +document.getElementById("window").value;
  const series = Object.entries(history).filter(([, h]) => h.length);
  let tmax = -Infinity;
  for (const [, h] of series) tmax = Math.max(tmax, h[h.length - 1][0]);
  if (!isFinite(tmax)) { svg.innerHTML = `<text x="${L}" y="${H / 2}">no position values yet</text>`; return; }
  const tmin = tmax - win;
  let lo = Infinity, hi = -Infinity;
  for (const [, h] of series) for (const [t, v] of h) if (t >= tmin) { lo = Math.min(lo, v); hi = Math.max(hi, v); }
  if (hi === lo) { hi += 1; lo -= 1; }
  const pad = (hi - lo) * 0.05; lo -= pad; hi += pad;
  const x = t => L + (t - tmin) / win * (W - L - R), y = v => T + (hi - v) / (hi - lo) * (H - T - B);
  let out = "";
  for (const v of ticks(lo, hi, 5))
    out += `<line class="grid" x1="${L}" x2="${W - R}" y1="${y(v)}" y2="${y(v)}"/>` +
           `<text class="ytick" x="${L - 5}" y="${y(v) + 4}" text-anchor="end">${v}</text>`;
  for (const t of ticks(tmin, tmax, 6))
    out += `<line class="grid" x1="${x(t)}" x2="${x(t)}" y1="${T}" y2="${H - B}"/>` +
           `<text class="xtick" x="${x(t)}" y="${H - B + 14}" text-anchor="middle">${t}</text>`;
  out += `<line x1="${L}" x2="${L}" y1="${T}" y2="${H - B}" stroke="#333"/>` +
         `<line x1="${L}" x2="${W - R}" y1="${H - B}" y2="${H - B}" stroke="#333"/>` +
         `<text class="xlabel" x="${(L + W) / 2}" y="${H - 4}" text-anchor="middle">time (s)</text>` +
         `<text class="ylabel" x="12" y="${(T + H - B) / 2}" transform="rotate(-90 12 ${(T + H - B) / 2})"
            text-anchor="middle">position (increments)</text>`;
  let legend = "";
  series.forEach(([key, h], i) => {
    const pts = h.filter(([t]) => t >= tmin).map(([t, v]) => `${x(t).toFixed(1)},${y(v).toFixed(1)}`);
    out += `<polyline class="trace" data-key="${esc(key)}" fill="none" stroke="${COLORS[i % COLORS.length]}"
              stroke-width="1.5" points="${pts.join(" ")}"/>`;
    legend += `<span><i style="background:${COLORS[i % COLORS.length]}"></i>${esc(key)}</span>`;
  });
  svg.innerHTML = out;
  document.getElementById("legend").innerHTML = legend;
}
const log = document.getElementById("log");
const source = new EventSource("/events");
source.addEventListener("state", e => showState(JSON.parse(e.data)));
function shown(ev) {
  for (const kind of ["heartbeat", "pdo", "sync"])
    if (ev.kind === kind && document.getElementById("hide-" + kind).checked) return false;
  const grep = document.getElementById("grep").value;
  return !grep || ev.text.includes(grep) || ev.bus.includes(grep);
}
document.getElementById("window").addEventListener("change", draw);
document.getElementById("pause").addEventListener("change", draw);
source.addEventListener("log", e => {
  const ev = JSON.parse(e.data);
  record(ev);
  if (!shown(ev)) return;
  const line = document.createElement("div");
  line.textContent = `${ev.t.toFixed(6)}  ${ev.bus}  ${ev.text}`;
  log.appendChild(line);
  while (log.childNodes.length > 500) log.removeChild(log.firstChild);
  log.scrollTop = log.scrollHeight;
});
</script>
</body></html>
"""
