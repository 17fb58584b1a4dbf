"""Every code block in README.md and docs/ runs as written ("Errors a user can act on").

How each fenced block is checked, by its language:

* ``python``: run in a fresh interpreter (the doc's work folder as cwd); it must exit 0 and print
  nothing on stderr (no warnings, no "was not properly shut down").
* ``sh`` / ``shell`` / ``bash`` / ``console``: the lines after ``$ `` are the commands (or every
  line that is not a comment, when no line has a prompt); output lines are not compared. They
  run with ``set -e`` in bash, with this interpreter's ``bin`` folder first on PATH.
* ``toml``: a rig file (fragments get a ``[[bus]] name = "can0"``): it must load through the rig
  config, and a rig built from it must start and close in real time, as under ``gatewaylab run``
  (without bus endpoints).
* anything else (``text``, no language): not code, not run.

HTML comments right before a fence steer it:

* ``<!-- skip: REASON -->``: not run (a toml block is still loaded), reported as skipped with REASON,
  e.g. it needs root or a veth pair;
* ``<!-- file: NAME -->``: the block's text is also written to NAME in the work folder, for the
  blocks after it (e.g. the rig file a later ``gatewaylab run`` uses);
* ``<!-- output -->``: a shell block with prompts whose output lines are compared too: each command's
  stdout must be exactly the lines printed under it (the README's examples stay true);
* ``<!-- background -->``: a shell block that keeps running (``gatewaylab run ... --ready-file F``):
  started, awaited until F exists, stopped with SIGTERM after the doc's last block.

The blocks of one document run in order and share one work folder: a block runs only after every
block before it ran, and fails (naming them) when one of them failed -- it may depend on what they did.
A skipped block (``skip`` marker) is not a failure.
"""

from __future__ import annotations

import os
import re
import shlex
import signal
import subprocess
import sys
import time
import tomllib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
SHELLS = {"sh", "shell", "bash", "console"}
RUN = {"python", "toml"} | SHELLS
FENCE = re.compile(r"^(\s*)(```+|~~~+)\s*([\w+-]*)")
MARKER = re.compile(r"^\s*<!--\s*([\w-]+)\s*(?::\s*(.*?))?\s*-->\s*$")
BLOCK_TIMEOUT = 60.0


@dataclass
class Block:
    doc: Path
    line: int
    lang: str
    text: str
    markers: dict[str, str]

    @property
    def id(self) -> str:
        doc = self.doc.relative_to(ROOT) if self.doc.is_relative_to(ROOT) else self.doc.name
        return f"{doc}:{self.line}-{self.lang}"


def extract(doc: Path) -> list[Block]:
    """The fenced blocks of a Markdown file with the markers in the comment lines right above them."""
    blocks: list[Block] = []
    lines = doc.read_text().splitlines()
    i = 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        indent, fence, lang = m.group(1), m.group(2), m.group(3).lower()
        markers: dict[str, str] = {}
        j = i - 1
        while j >= 0 and (mm := MARKER.match(lines[j])):
            markers.setdefault(mm.group(1), mm.group(2) or "")
            j -= 1
        body: list[str] = []
        k = i + 1
        while k < len(lines) and not lines[k].strip().startswith(fence):
            body.append(lines[k][len(indent):] if lines[k].startswith(indent) else lines[k])
            k += 1
        blocks.append(Block(doc, i + 1, lang, "\n".join(body) + "\n", markers))
        i = k + 1
    return blocks


def shell_commands(text: str) -> list[str]:
    lines = text.splitlines()
    joined: list[str] = []
    for line in lines:
        if joined and joined[-1].endswith("\\"):
            joined[-1] = joined[-1][:-1] + " " + line.strip()
        else:
            joined.append(line)
    if any(line.startswith("$ ") for line in joined):
        return [line[2:] for line in joined if line.startswith("$ ")]
    return [line for line in joined if line.strip() and not line.lstrip().startswith("#")]


_SENTINEL = "@@gatewaylab-docs-next-command@@"


def expected_outputs(text: str) -> list[list[str]]:
    """The output lines printed under each ``$ `` command of a block."""
    out: list[list[str]] = []
    for line in text.splitlines():
        if line.startswith("$ "):
            out.append([])
        elif out:
            out[-1].append(line)
    return out


@dataclass
class DocSession:
    """The work folder and background processes of one document's blocks."""

    workdir: Path
    blocks: list[Block]
    done: int = 0
    background: list[subprocess.Popen[str]] = field(default_factory=list)
    #: index -> why: the blocks that failed so far (as prerequisites or in their own test)
    failed: dict[int, str] = field(default_factory=dict)

    def env(self) -> dict[str, str]:
        bin_dir = str(Path(sys.executable).parent)
        return {**os.environ, "PATH": bin_dir + os.pathsep + os.environ.get("PATH", ""),
                "PYTHONUNBUFFERED": "1", "PYTHONWARNINGS": "always::ResourceWarning"}

    def run(self, index: int) -> None:
        """Run the blocks before ``index`` not run yet (they have their own tests too), then it; it fails
        without running when a block before it failed (a skipped one does not count)."""
        while self.done < index:
            self._attempt(self.done)
        self.done = index + 1
        before = {i: why for i, why in self.failed.items() if i < index}
        if before:
            self.failed[index] = "a block before it failed"
            raise AssertionError(f"{self.blocks[index].id}: blocks before it failed, so it cannot run as written:\n"
                                 + "\n".join(f"{self.blocks[i].id}: {why}" for i, why in sorted(before.items())))
        self._attempt(index, reraise=True)

    def _attempt(self, index: int, reraise: bool = False) -> None:
        """Run one block; a failure is recorded for the blocks after it (and raised with ``reraise``)."""
        self.done = max(self.done, index + 1)
        try:
            self._run(self.blocks[index])
        except pytest.skip.Exception:
            if reraise:
                raise
        except Exception as exc:
            self.failed[index] = f"{type(exc).__name__}: {str(exc).strip()[:500]}"
            if reraise:
                raise

    def _run(self, block: Block) -> None:
        if "file" in block.markers:
            (self.workdir / block.markers["file"]).write_text(block.text)
        if block.lang == "toml":
            self._toml(block)
            return
        if "skip" in block.markers:
            pytest.skip(block.markers["skip"] or "marked skip")
        if block.lang == "python":
            self._python(block)
        else:
            self._shell(block)

    def _python(self, block: Block) -> None:
        r = subprocess.run([sys.executable, "-c", block.text], cwd=self.workdir, env=self.env(),
                           capture_output=True, text=True, timeout=BLOCK_TIMEOUT)
        assert r.returncode == 0 and not r.stderr.strip(), f"{block.id} failed:\n{r.stderr}"

    def _shell(self, block: Block) -> None:
        commands = shell_commands(block.text)
        assert commands, f"{block.id}: no command in the block"
        if "background" in block.markers:
            assert len(commands) == 1, f"{block.id}: a background block holds one command"
            self._background(block, commands[0])
            return
        if "output" in block.markers:
            commands = [f"echo {_SENTINEL}\n{c}" for c in commands]
        script = "set -euo pipefail\n" + "\n".join(commands) + "\n"
        r = subprocess.run(["bash", "-c", script], cwd=self.workdir, env=self.env(), capture_output=True,
                           text=True, timeout=BLOCK_TIMEOUT)
        assert r.returncode == 0, f"{block.id} failed (exit {r.returncode}):\n{r.stdout}\n{r.stderr}"
        if "output" in block.markers:
            got = [part.strip("\n").splitlines() for part in r.stdout.split(_SENTINEL + "\n")[1:]]
            assert got == expected_outputs(block.text), f"{block.id}: the output differs from the document"

    def _background(self, block: Block, command: str) -> None:
        words = shlex.split(command)
        assert "--ready-file" in words, f"{block.id}: a background command needs --ready-file"
        ready = self.workdir / words[words.index("--ready-file") + 1]
        proc = subprocess.Popen(["bash", "-c", "exec " + command], cwd=self.workdir, env=self.env(),
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        self.background.append(proc)
        deadline = time.monotonic() + BLOCK_TIMEOUT
        while not ready.exists():
            try:
                proc.wait(0.05)
            except subprocess.TimeoutExpired:
                assert time.monotonic() < deadline, f"{block.id}: {ready.name} not written"
                continue
            raise AssertionError(f"{block.id} exited {proc.returncode}: {proc.stderr.read() if proc.stderr else ''}")

    def _toml(self, block: Block) -> None:
        from gatewaylab.common.clock import RealTimeClock
        from gatewaylab.rig import Rig, parse_rig

        data = tomllib.loads(block.text)
        if "bus" not in data:
            data["bus"] = [{"name": "can0"}]
        config = parse_rig(data, block.id)
        if "skip" in block.markers:
            pytest.skip(f"loaded only: {block.markers['skip']}")
        rig = Rig(config, clock=RealTimeClock(), endpoints=False)
        try:
            rig.start()
            rig.poll(0.0)
        finally:
            rig.close()

    def close(self) -> None:
        for proc in self.background:
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
                try:
                    proc.wait(10)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
            if proc.stderr is not None:
                proc.stderr.close()


ALL_BLOCKS = [b for doc in DOCS for b in extract(doc)]
RUNNABLE = [b for b in ALL_BLOCKS if b.lang in RUN]
_sessions: dict[Path, DocSession] = {}


@pytest.fixture(scope="module", autouse=True)
def _close_sessions() -> Iterator[None]:
    yield
    for session in _sessions.values():
        session.close()
    _sessions.clear()


@pytest.mark.parametrize("block", RUNNABLE, ids=[b.id for b in RUNNABLE])
def test_doc_block_runs_as_written(block: Block, tmp_path_factory: pytest.TempPathFactory) -> None:
    """"Every code block in README.md and docs/ runs as written"."""
    session = _sessions.get(block.doc)
    if session is None:
        blocks = [b for b in RUNNABLE if b.doc == block.doc]
        session = _sessions[block.doc] = DocSession(tmp_path_factory.mktemp(block.doc.stem), blocks)
    session.run(session.blocks.index(block))


def test_the_extractor_sees_markers_and_prompts(tmp_path: Path) -> None:
    """The harness itself: markers above a fence are read, prompts select commands."""
    doc = tmp_path / "x.md"
    doc.write_text("text\n<!-- skip: needs root -->\n```sh\n$ echo hi\nhi\n```\n\n```python\nprint(1)\n```\n")
    blocks = extract(doc)
    assert [(b.lang, b.markers) for b in blocks] == [("sh", {"skip": "needs root"}), ("python", {})]
    assert shell_commands(blocks[0].text) == ["echo hi"]
    assert shell_commands("# comment\nmake demo  # x\n") == ["make demo  # x"]
    assert expected_outputs("$ a\n1\n2\n$ b\n$ c  # x\n3\n") == [["1", "2"], [], ["3"]]


def test_a_block_after_a_failed_one_fails(tmp_path: Path) -> None:
    """A block that would pass on its own fails when a block before it (its prerequisite in the shared work
    folder) failed: the later block names it, and a skipped block before it does not count."""
    doc = tmp_path / "x.md"
    doc.write_text("<!-- skip: not here -->\n```python\nraise SystemExit(3)\n```\n\n"
                   "```python\nraise SystemExit(1)\n```\n\n```python\nprint('fine')\n```\n")
    blocks = extract(doc)
    session = DocSession(tmp_path, blocks)
    with pytest.raises(AssertionError) as failed:
        session.run(2)
    assert blocks[1].id in str(failed.value) and blocks[0].id not in str(failed.value)
    alone = DocSession(tmp_path, blocks[2:])
    alone.run(0)                     # the same block with nothing before it passes

