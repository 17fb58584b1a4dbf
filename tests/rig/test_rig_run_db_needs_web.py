"""``gatewaylab run --db FILE`` without ``--web`` (issue 25, exit-code table of docs/cli.md): the signal
database only decodes on the web page, so alone it is a usage error (exit 2, one line) instead of being
silently ignored; the rig does not start (no ready file)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path


def test_db_without_web_is_a_usage_error(tmp_path: Path) -> None:
    dbc = tmp_path / "signals.dbc"
    dbc.write_text('VERSION ""\n\nBU_:\n\nBO_ 256 Frame: 8 Vector__XXX\n SG_ speed : 0|16@1+ (1,0) [0|65535] "" '
                   "Vector__XXX\n")
    ready = tmp_path / "ready.json"
    out = subprocess.run([sys.executable, "-m", "gatewaylab", "run", "--db", str(dbc), "--ready-file", str(ready)],
                         capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert out.returncode == 2, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in out.stderr
    assert f"--db {dbc} decodes signals on the --web page: give --web too" in lines[0]
    assert not ready.exists()
