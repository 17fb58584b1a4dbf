"""`make conformance`: python-can's and canopen's own test suites against a rig, on the `gatewaylab` interface.

1. Downloads the sdists of the INSTALLED python-can and canopen versions from the package index
   into ``.venv/conformance/`` (once; ``pip download --no-deps --no-binary :all:``).
2. Copies their test folders (renamed so both fit in one pytest run and the installed packages, not
   the sdists' sources, are the ones imported).
3. Starts ``gatewaylab run`` with eight CAN FD buses and ``--acker`` (the suites assume vcan-style
   loopback, where a lone node's frame is acknowledged; docs/bus.md "A lone node").
4. Runs the selected test files through the shim ``gatewaylab_conformance.py`` (every
   ``interface="virtual"`` bus becomes a connection to a rig bus), skipping only what
   ``inapplicable.toml`` lists, each with its reason; and ``gatewaylab_polling_test.py``, the
   polling loops python-can programs write (``recv(0)`` in a cyclic task, ``recv(timeout)``).
5. Stops the rig and removes its files on every exit (also on Ctrl-C and SIGTERM).

Arguments go to pytest; any that names a test file (``python_can_test/notifier_test.py``, a node id)
replaces the default selection. Exit status: pytest's (0 when every applicable test passed).
"""

from __future__ import annotations

import importlib.metadata
import os
import shutil
import signal
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path
from types import FrameType

from gatewaylab.rig.process import RigProcess

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
WORK = ROOT / ".venv" / "conformance"

#: suite -> (distribution, sdist test folder, folder name here, test files)
SUITES = {
    "python-can": ("python-can", "test", "python_can_test", [
        "back2back_test.py", "simplecyclic_test.py", "notifier_test.py", "listener_test.py",
        "test_message_filtering.py", "test_bus.py"]),
    "canopen": ("canopen", "test", "canopen_test", [
        "test_emcy.py", "test_local.py", "test_network.py", "test_nmt.py", "test_node.py", "test_sync.py"]),
}

#: the check of our own: python-can polling loops (recv(0) in a cyclic task, recv(timeout)) on the interface
POLLING = HERE / "gatewaylab_polling_test.py"

RIG = "clock = \"realtime\"\n" + "".join(
    f"[[bus]]\nname = \"vbus{i}\"\nbitrate = 1000000\ndata_bitrate = 8000000\n" for i in range(8))


def _sdist(dist: str, version: str) -> Path:
    sdists = WORK / "sdist"
    sdists.mkdir(parents=True, exist_ok=True)
    stem = dist.replace("-", "_").lower()
    for path in sdists.glob("*.tar.gz"):
        name = path.name.lower()
        if name.startswith((f"{stem}-{version}.", f"{dist.lower()}-{version}.")):
            return path
    print(f"conformance: downloading the {dist} {version} sdist", flush=True)
    subprocess.run([sys.executable, "-m", "pip", "download", "--quiet", "--no-deps", "--no-binary", ":all:",
                    f"{dist}=={version}", "-d", str(sdists)], check=True)
    return _sdist(dist, version)


def _extract_tests(archive: Path, folder: str, dest: Path) -> None:
    if dest.exists():
        shutil.rmtree(dest)
    with tarfile.open(archive) as tar:
        top = tar.getnames()[0].split("/")[0]
        prefix = f"{top}/{folder}/"
        members = [m for m in tar.getmembers() if m.name.startswith(prefix) and (m.isfile() or m.isdir())]
        tmp = dest.parent / f".{dest.name}.tmp"
        if tmp.exists():
            shutil.rmtree(tmp)
        tar.extractall(tmp, members=members, filter="data")
    (tmp / top / folder).rename(dest)
    shutil.rmtree(tmp)


def main(argv: list[str]) -> int:
    def terminate(signum: int, frame: FrameType | None) -> None:
        raise SystemExit(128 + signum)

    signal.signal(signal.SIGTERM, terminate)
    suites_dir = WORK / "suites"
    suites_dir.mkdir(parents=True, exist_ok=True)
    targets: list[str] = []
    for dist, folder, name, files in SUITES.values():
        version = importlib.metadata.version(dist)
        _extract_tests(_sdist(dist, version), folder, suites_dir / name)
        targets += [f"{name}/{f}" for f in files]
        print(f"conformance: {dist} {version}: {', '.join(files)}", flush=True)
    targets.append(str(POLLING))
    state = Path(tempfile.mkdtemp(prefix="gatewaylab-conformance-"))
    rig: RigProcess | None = None
    try:
        rig_file = state / "conformance.toml"
        rig_file.write_text(RIG)
        rig = RigProcess(rig_file, "--acker", workdir=state, stderr=sys.stderr)
        env = {**os.environ, "GATEWAYLAB_CONFORMANCE_READY": str(rig.ready_file),
               "PYTHONPATH": os.pathsep.join(filter(None, [str(HERE), os.environ.get("PYTHONPATH")]))}
        info = rig.info
        print(f"conformance: rig pid {info['pid']}, {len(info['buses'])} buses, --acker", flush=True)
        result = subprocess.run([sys.executable, "-m", "pytest", "-c", str(HERE / "pytest.ini"),
                                 "--rootdir", str(suites_dir), "-p", "gatewaylab_conformance", "-q",
                                 *(argv if any(".py" in a for a in argv) else [*targets, *argv])],
                                cwd=suites_dir, env=env)
        return result.returncode
    finally:
        if rig is not None:
            rig.stop()
        shutil.rmtree(state, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
