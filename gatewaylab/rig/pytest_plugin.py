"""gatewaylab's pytest plugin (the ``pytest11`` entry point): rigs as fixtures for a user's own tests of
their master software (docs/testing-your-master.md).

* ``gatewaylab_rig``: a factory fixture. ``gatewaylab_rig(RIG)`` (a rig file, a dict in the rig-file
  shape, or None for the default rig) starts ``gatewaylab run`` as a child process (``clock =
  "realtime"``, the default: what a master in another process talks to), or an in-process rig
  (``in_process=True``, run by a thread) or a simulated one (``clock="simulated"``: the test drives
  ``handle.clock``). Every rig has its own state folder (its Unix sockets) and the test its own
  work folder; TCP ports left at 0 are chosen by the OS, so parallel pytest-xdist workers never
  collide. Everything is stopped and removed when the test ends.
* markers ``gatewaylab_root`` (the test needs root) and ``gatewaylab_veth`` (it needs veth pairs and
  raw sockets: root or CAP_NET_ADMIN + CAP_NET_RAW and iproute2): such tests are skipped, with the
  reason, where the process lacks it.
* marker ``gatewaylab_scenario("steps.toml")`` (a scenario file, relative to the test file's folder) or
  ``gatewaylab_scenario(steps=[{...}, ...])`` (the ``[[scenario]]`` tables as dicts): every rig the test
  starts with ``gatewaylab_rig`` fires those steps (``scenario=`` of the factory overrides it).
"""

from __future__ import annotations

import json
import os
import tomllib
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest

if TYPE_CHECKING:
    import can

    from gatewaylab.common.clock import Clock
    from gatewaylab.rig.process import RigProcess
    from gatewaylab.rig.runtime import Rig

from gatewaylab.common.ask import ask, endpoint_address
from gatewaylab.common.endpoint import EndpointKind, parse_endpoint
from gatewaylab.common.errors import ConfigError
from gatewaylab.rig.process import free_udp_ports, rig_toml

__all__ = ["RigHandle", "free_udp_ports", "rig_toml"]

#: How errors name a rig given as a dict: "rig dict [[bus]] #1 (can0): unknown keys ['bitrat'] ...".
DICT_SOURCE = "rig dict"

MARKERS = {
    "gatewaylab_root": "the test needs root (skipped otherwise)",
    "gatewaylab_veth": "the test needs veth pairs and raw sockets: root or CAP_NET_ADMIN + CAP_NET_RAW and "
                       "iproute2 (skipped otherwise)",
    "gatewaylab_scenario": "gatewaylab_scenario(FILE) or gatewaylab_scenario(steps=[...]): the rigs the test starts "
                           "with gatewaylab_rig fire these [[scenario]] steps (docs/faults.md 'Scenarios')",
}
#: How errors name steps given as dicts: "scenario steps [[scenario]] #2: needs a trigger ...".
STEPS_SOURCE = "scenario steps"
#: A scenario: a file (path) or the steps as dicts.
ScenarioSpec = str | Path | list[Mapping[str, Any]] | tuple[Mapping[str, Any], ...]


class RigHandle:
    """One rig started by ``gatewaylab_rig``: its ready-file contents, endpoints and python-can buses."""

    def __init__(self, workdir: Path, info: dict[str, Any], *, rig: Rig | None = None,
                 process: RigProcess | None = None) -> None:
        self.workdir = workdir
        #: the ready file's contents (``gatewaylab run --ready-file``): pid, buses, control, canopen ...
        self.info = info
        #: the in-process rig (in_process or simulated), else None
        self.rig = rig
        #: the ``gatewaylab run`` child, else None
        self.process = process
        self._buses: list[can.BusABC] = []
        self._thread: Any = None

    @property
    def clock(self) -> Clock:
        """The in-process rig's clock (a simulated one is driven with advance()/run_until())."""
        if self.rig is None:
            raise AttributeError("a rig in a child process has no clock here; use in_process=True")
        return self.rig.clock

    def endpoint(self, bus: str = "can0") -> str:
        """The bus's endpoint (``unix:PATH`` / ``tcp:HOST:PORT``) for ``can.Bus(interface="gatewaylab")``."""
        return str(self.info["buses"][bus]["endpoint"])

    def socketcand(self, bus: str = "can0") -> int:
        """The bus's socketcand port on 127.0.0.1 (the rig needs ``socketcand = true`` or ``--socketcand``)."""
        return int(self.info["buses"][bus]["socketcand"])

    def eds(self, drive: str, bus: str = "can0") -> str:
        """The EDS file of a ``[[drive]]`` (for ``canopen.Network.add_node``)."""
        return str(self.info["canopen"][bus][drive]["eds"])

    def can_bus(self, bus: str = "can0", **kwargs: Any) -> can.BusABC:
        """A python-can bus on a rig bus, shut down when the test ends: through the endpoint for a rig in
        a child process, in process otherwise."""
        if self.rig is not None:
            from gatewaylab.bus import python_can_bus

            made: can.BusABC = python_can_bus(self.rig.bus(bus), **kwargs)
        else:
            import can

            made = can.Bus(interface="gatewaylab", channel=self.endpoint(bus), **kwargs)
        self._buses.append(made)
        return made

    def fault(self, name: str, **arguments: Any) -> dict[str, Any]:
        """Inject fault ``name`` (a ``gatewaylab fault`` verb, e.g. ``"ec-lose"``) with the control request's
        arguments (docs/faults.md), in process or through the control endpoint; the rig's answer.
        A refused fault raises :class:`~gatewaylab.rig.faults_core.FaultRefused` with the rig's reason."""
        request = {"fault": name, **arguments}
        if self.rig is not None:
            return self.rig.faults.request(request)
        endpoint = parse_endpoint(str(self.info["control"]), bare_path=EndpointKind.UNIX)
        answer: dict[str, Any] = json.loads(ask(endpoint_address(endpoint), request, 10.0) or b"{}")
        if not answer.get("ok"):
            from gatewaylab.rig.faults_core import FaultRefused  # the plugin loads in every pytest run: light

            raise FaultRefused(f"fault {name} refused: {answer.get('error', answer)}")
        return answer

    def stop(self) -> None:
        """Shut down its python-can buses, then the rig (idempotent)."""
        for made in self._buses:
            made.shutdown()
        self._buses.clear()
        if self.process is not None:
            self.process.stop()
        if self.rig is not None:
            self.rig.request_stop()
            if self._thread is not None:
                self._thread.join(10)
            self.rig.close()


def _scenario(workdir: Path, scenario: ScenarioSpec | None) -> tuple[tuple[Any, ...], Path | None]:
    """The steps (checked here, in the test's process) and the file a ``gatewaylab run`` child reads them from."""
    if scenario is None:
        return (), None
    from gatewaylab.rig.scenario import load_scenario, parse_scenario

    if isinstance(scenario, (str, Path)):
        path = Path(scenario).resolve()
        return load_scenario(path), path
    steps = parse_scenario([dict(step) for step in scenario], STEPS_SOURCE)
    path = workdir / "scenario.toml"
    path.write_text(rig_toml({"scenario": [step.as_json() for step in steps]}))
    return steps, path


def _marked_scenario(node: pytest.Item | None) -> ScenarioSpec | None:
    """The ``gatewaylab_scenario`` marker's scenario (a file relative to the test file's folder), else None."""
    marker = None if node is None else node.get_closest_marker("gatewaylab_scenario")
    if marker is None or node is None:
        return None
    steps = marker.kwargs.get("steps")
    if (steps is None) == (len(marker.args) != 1) or set(marker.kwargs) - {"steps"}:
        raise ConfigError("gatewaylab_scenario takes a scenario file or steps=[...], one of them: "
                          f"got args {marker.args!r}, kwargs {sorted(marker.kwargs)}")
    if steps is not None:
        if not isinstance(steps, (list, tuple)):
            raise ConfigError(f"gatewaylab_scenario(steps=...) must be a list of step dicts, got {steps!r}")
        return list(steps)
    return Path(node.path).parent / Path(marker.args[0])


def _start(workdir: Path, rig: str | Path | Mapping[str, Any] | None, clock: str, in_process: bool,
           args: tuple[str, ...], timeout: float, scenario: ScenarioSpec | None = None) -> RigHandle:
    if clock not in ("realtime", "simulated"):
        raise ConfigError(f"clock must be 'realtime' or 'simulated', not {clock!r}")
    from gatewaylab.rig.config import load_rig, parse_rig

    child = clock == "realtime" and not in_process
    # Checked here, in the test's process, whatever the clock: a mistake is the same ConfigError naming the
    # user's key (and the user's file, or "rig dict"), never a start that "timed out" in a child.
    path: Path | None = None
    if isinstance(rig, Mapping):
        text = rig_toml({**rig, "clock": "realtime"} if child else rig)
        config = parse_rig(tomllib.loads(text), DICT_SOURCE)    # what the child reads, named as the user wrote it
        if child:
            path = workdir / "rig.toml"
            path.write_text(text)
    else:
        path = None if rig is None else Path(rig)
        config = load_rig(path)
    steps, scenario_file = _scenario(workdir, scenario)
    if child:
        if scenario_file is not None:
            args = (*args, "--scenario", str(scenario_file))
        from gatewaylab.rig.process import RigProcess

        process = RigProcess(path, *args, workdir=workdir, timeout=timeout)
        return RigHandle(workdir, process.info, process=process)
    if args:
        raise ConfigError("args are `gatewaylab run` options: only for a rig in a child process")
    from gatewaylab.common.clock import RealTimeClock, SimulatedClock
    from gatewaylab.rig.runtime import Rig

    if steps:
        from dataclasses import replace

        config = replace(config, scenario=steps)
    instance = Rig(config, clock=SimulatedClock() if clock == "simulated" else RealTimeClock())
    handle = RigHandle(workdir, {}, rig=instance)
    try:
        instance.start()
        if clock == "realtime":
            handle._thread = instance.run_in_thread()
        handle.info = instance.ready_info()
    except BaseException:
        handle.stop()
        raise
    return handle


@pytest.fixture
def gatewaylab_rig(tmp_path_factory: pytest.TempPathFactory,
                   request: pytest.FixtureRequest) -> Iterator[Callable[..., RigHandle]]:
    """``gatewaylab_rig(rig=None, *, clock="realtime", in_process=False, args=(), timeout=60.0,
    scenario=None)`` -> :class:`RigHandle`; every rig it started is stopped when the test ends. ``scenario``
    (a scenario file or a list of step dicts) defaults to the test's ``gatewaylab_scenario`` marker."""
    handles: list[RigHandle] = []
    marked = _marked_scenario(request.node if isinstance(request.node, pytest.Item) else None)

    def start(rig: str | Path | Mapping[str, Any] | None = None, *, clock: str = "realtime",
              in_process: bool = False, args: tuple[str, ...] | list[str] = (), timeout: float = 60.0,
              scenario: ScenarioSpec | None = None) -> RigHandle:
        workdir = tmp_path_factory.mktemp("gatewaylab-rig")
        handle = _start(workdir, rig, clock, in_process, tuple(args), timeout,
                        marked if scenario is None else scenario)
        handles.append(handle)
        return handle

    yield start
    for handle in reversed(handles):
        handle.stop()


def pytest_configure(config: pytest.Config) -> None:
    """Register the plugin's markers (so --strict-markers accepts them)."""
    for name, text in MARKERS.items():
        config.addinivalue_line("markers", f"{name}: {text}")


def _veth_unavailable() -> str | None:
    from gatewaylab.ethercat.wire_netns import net_unavailable

    return net_unavailable()


def pytest_runtest_setup(item: pytest.Item) -> None:
    """Skip tests marked for root or veth pairs where those are not available."""
    if item.get_closest_marker("gatewaylab_root") is not None and os.geteuid() != 0:
        pytest.skip("needs root (marked gatewaylab_root)")
    if item.get_closest_marker("gatewaylab_veth") is not None:
        reason = _veth_unavailable()
        if reason is not None:
            pytest.skip(f"needs veth pairs (marked gatewaylab_veth): {reason}")
