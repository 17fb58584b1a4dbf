"""What every KickCAT driver of the suite does before its first frame, as KickCAT's README tells users to."""

from __future__ import annotations

import contextlib
import os

__all__ = ["run_as_kickcat_readme_says"]


def run_as_kickcat_readme_says() -> None:
    """SCHED_FIFO priority 3, as KickCAT's README (Performance Optimization: ``chrt -f 80``) runs a master:
    its socket read sleeps 20 us between polls and gives up once a sleep overran the deadline without a last
    look (Socket::read), so an ordinary process waiting for a CPU loses replies that came in time. Below the
    emulator's wire thread (10) and loop (5): the line is hardware. Nothing without the privilege."""
    with contextlib.suppress(OSError):
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(3))
