"""``gatewaylab ec`` FoE verbs: ``foe-read`` and ``foe-write``, with ``--boot`` and a progress bar."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO

from gatewaylab.cli.ec_args import EcRefused, binary_out, one_slave, read_input
from gatewaylab.common.clock import Clock
from gatewaylab.ethercat.esc import AlState
from gatewaylab.hosts.ethercat.backend import MasterBackend, ProgressFn
from gatewaylab.hosts.ethercat.states import state_path

__all__ = ["cmd_foe_read", "cmd_foe_write"]


@contextmanager
def _progress(args: argparse.Namespace, clock: Clock, what: str, total: int | None) -> Iterator[ProgressFn | None]:
    """A rich progress bar on stderr when it is a terminal (or ``--progress``), else nothing; its
    speed is measured on the backend's clock (simulated time in process)."""
    show = args.progress if args.progress is not None else sys.stderr.isatty()
    if not show:
        yield None
        return
    from rich.console import Console
    from rich.progress import BarColumn, DownloadColumn, Progress, TextColumn, TransferSpeedColumn

    console = Console(stderr=True)     # not a terminal (--progress): rich prints the finished bar once
    with Progress(TextColumn("{task.description}"), BarColumn(), DownloadColumn(), TransferSpeedColumn(),
                  console=console, transient=False, get_time=clock.now) as bar:
        task = bar.add_task(what, total=total)

        def update(done: int, _total: int) -> None:
            bar.update(task, completed=done)

        yield update
        bar.update(task, total=bar.tasks[0].completed, completed=bar.tasks[0].completed)


@contextmanager
def _boot(backend: MasterBackend, pos: int, boot: bool) -> Iterator[None]:
    """``--boot``: INIT -> BOOT around the transfer and back to INIT (a firmware update, ETG.1000.6
    bootstrap state), what ``ethercat states BOOT`` before the transfer does on IgH's master."""
    if not boot:
        yield
        return
    for step in state_path(backend.state(pos)[0], AlState.BOOT):
        backend.request_state(step, pos)
    yield
    backend.request_state(AlState.INIT, pos)


def cmd_foe_read(backend: MasterBackend, args: argparse.Namespace, out: IO[str]) -> None:
    """IgH ``ethercat foe_read [-o FILE] NAME``: the file to stdout or to FILE."""
    pos = one_slave(backend, args)
    with _boot(backend, pos, args.boot), _progress(args, backend.clock, f"foe read {args.name}", None) as progress:
        data = backend.foe_read(pos, args.name, args.password, progress=progress)
    if args.output:
        try:
            Path(args.output).write_bytes(data)
        except OSError as exc:
            raise EcRefused(f"cannot write {args.output}: {exc.strerror or exc}") from None
        return
    out.flush()
    binary_out().write(data)


def cmd_foe_write(backend: MasterBackend, args: argparse.Namespace, out: IO[str]) -> None:
    """IgH ``ethercat foe_write [-o NAME] FILE``: FILE (``-`` = stdin) to the slave, named NAME
    (default: FILE's base name)."""
    pos = one_slave(backend, args)
    data: bytes = args.data if getattr(args, "data", None) is not None else read_input(args.file)
    name = args.name or Path(args.file).name
    with _boot(backend, pos, args.boot), _progress(args, backend.clock, f"foe write {name}", len(data)) as progress:
        backend.foe_write(pos, name, data, args.password, progress=progress)
