"""After a stall of the rig, replies on time or not at all (docs/rig.md ``[ethercat] max_residence_ms``).

The user's path: ``gatewaylab run`` with an ``[ethercat]`` segment (one ``ethercat_io``) on a veth end, a pysoem
master in the namespace cycling at 1 kHz with SOEM's default 2 ms receive timeout, the rig paused for 200 ms
(``kill -STOP``: what a VM or a loaded host does to a process) and continued. A real line loses a frame; it
never returns one 100 ms later (ETG.1000.4: a frame is processed on the fly and comes back within the line's
delay). The old wire answered every frame queued during the pause, up to 117 ms late, and SOEM matched
those replies to newer requests that reused their frame index (issue 31). Each cycle writes its number into
the io's loop-back outputs, so the master sees which request a reply answers (tests/userpath/
ethercat_stall_master.py): no reply may answer an older request, and the rig counts the frames it dropped.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import pytest
from ethercat_userpath_kit import ethercat_rig

from gatewaylab.common.ask import ask, endpoint_address
from gatewaylab.common.endpoint import EndpointKind, parse_endpoint

pytestmark = [pytest.mark.net, pytest.mark.slow]
MASTER = Path(__file__).with_name("ethercat_stall_master.py")
RIG = """
clock = "realtime"
[[device]]
kind = "ethercat_io"
name = "io1"
[ethercat]
interface = "{interface}"
"""
STALL_S = 0.2


def _states(info: dict[str, Any]) -> dict[str, Any]:
    endpoint = parse_endpoint(str(info["control"]), bare_path=EndpointKind.UNIX)
    answer: dict[str, Any] = json.loads(ask(endpoint_address(endpoint), {"fault": "ethercat-states"}, 10.0))
    return answer


def test_no_stale_reply_reaches_the_master_after_a_stall(tmp_path: Path) -> None:
    """200 ms ``kill -STOP`` of the rig while SOEM cycles at 1 kHz: 0 replies answer an older request (the
    frames queued during the pause are dropped, not answered late), the rig's ``frames_dropped_late`` > 0
    (control request ``ethercat-states``, docs/faults.md), and the line carries on after the pause."""
    with ethercat_rig(tmp_path, RIG) as user:
        proc = subprocess.Popen(["ip", "netns", "exec", user.namespace, sys.executable, str(MASTER),
                                 user.master_iface], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)
        assert proc.stdout is not None and proc.stdin is not None
        timer = threading.Timer(120, proc.kill)
        timer.start()
        try:
            line = proc.stdout.readline()
            assert json.loads(line or "{}").get("ev") == "op", proc.stderr.read() if proc.stderr else line
            threading.Event().wait(0.5)            # cycling in OP
            os.kill(user.rig.pid, signal.SIGSTOP)
            stopped = time.monotonic()
            threading.Event().wait(STALL_S)
            os.kill(user.rig.pid, signal.SIGCONT)
            print(f"rig stopped for {1e3 * (time.monotonic() - stopped):.0f} ms")
            proc.stdin.write("go on\n")
            proc.stdin.flush()
            done = json.loads(proc.stdout.readline() or "{}")
            proc.wait(60)
        finally:
            timer.cancel()
            if proc.poll() is None:
                proc.kill()
        assert done.get("ev") == "done", proc.stderr.read() if proc.stderr else done
        wire = _states(user.rig.info).get("wire", {})
    print(f"master: {done['cycles']} cycles, {done['good']} good, {done['lost']} lost, {done['stale']} stale "
          f"(ages {done['stale_ages_ms']} ms), oldest good reply {done['oldest_ms']:.1f} ms; rig wire: {wire}")
    assert done["stale"] == 0, done["stale_ages_ms"]
    assert wire.get("frames_dropped_late", 0) > 0, wire
    assert done["good"] > 100          # the line works around the pause
