"""The ECAN-Lite on the user's path (issue 21): ``gatewaylab run`` with the device on the ``[ethercat]``
segment of a veth pair, pysoem and KickCAT as masters in a namespace following manual 5.4.3 (phases A-E over
CoE: capabilities, 0x1C12/0x1C13 = 3 chunks, 0x8010/0x8011 profile, 0x8001.. MCAN channels; OP; 5.4.4.1
frames in the RxPDO; chapter 6 TxPDO parsing), python-can clients on can0 through the ready file's endpoint.
One rig for the module; every run measures the first frame after OP and the steady state both ways."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from ethercat_userpath_kit import (
    CanClient,
    NotifierClient,
    PollLoopClient,
    Session,
    TimeoutClient,
    UserRig,
    bounded,
    exchange,
    module_rig,
)

pytestmark = [pytest.mark.net, pytest.mark.slow]

RIG = """
clock = "realtime"

[[bus]]
name = "can0"
bitrate = 1000000
data_bitrate = 5000000

[[bus]]
name = "can1"
bitrate = 1000000
data_bitrate = 5000000

[[device]]
kind = "ecanlite"
name = "ecan"
channels = ["can0", "can1"]

[ethercat]
interface = "{interface}"
"""


@pytest.fixture(scope="module")
def user(tmp_path_factory: pytest.TempPathFactory) -> Iterator[UserRig]:
    yield from module_rig(tmp_path_factory, RIG, ["ecan"])


def check_stream(s: Session) -> None:
    """OP; every TxPDO image parsed (chapter 6: header, CRC), each frame on CAN once; nothing lost while every
    cycle was good."""
    assert s.done is not None and s.done["op"] == "OP"
    assert s.done["stream_errors"] == [] and s.client.duplicates == []
    if s.done["bad_wkc"] == 0:
        assert s.m2c.missing == [] and s.c2m.missing == []


def run(user: UserRig, lib: str, client: type[CanClient]) -> None:
    """A session of ``lib`` with a fresh ``client``, checked, within the bounds (:func:`bounded`)."""
    def session() -> Session:
        return exchange(user, lib, "ecanlite", client(user.endpoint()))
    bounded(session(), session, check_stream)


def test_soem_master_with_a_recv0_poll_loop(user: UserRig) -> None:
    """Manual 5.4.3 with SOEM, then 5.4.4.1: a frame written at offset 24 of the RxPDO reaches CAN0 (a
    new header sequence per frame, the repeated image an idempotent no-op, 13.8: each frame exactly once);
    a python-can node's frames come up in the TxPDO (chapter 8). The client drains the bus in a 1 ms cyclic
    task with ``recv(0)``. First frame after OP < 100 ms, steady p99 < 50 ms, both directions."""
    run(user, "soem", PollLoopClient)


def test_kickcat_master_with_a_notifier(user: UserRig) -> None:
    """The same bring-up (5.4.3 A-E) through KickCAT's mailbox, its create_mapping reading the new
    assignment (3 chunks), OP, frames both ways; the client is a ``can.Notifier`` feeding a
    ``BufferedReader``. Same bounds."""
    run(user, "kickcat", NotifierClient)


def test_a_killed_master_is_replaced_without_restarting_the_rig(user: UserRig) -> None:
    """A master process SIGKILLed mid-exchange leaves the device in OP with nobody cycling; a new master
    process scans (INIT), runs the start-up of 14.1 again (5.4.3: assignment, profile, MCAN channels) and
    brings the same rig process back to OP, and frames flow both ways again within the bounds."""
    pid = user.rig.pid
    first = exchange(user, "soem", "ecanlite", TimeoutClient(user.endpoint()), kill_after=0.5)
    assert first.master.proc.returncode == -9
    run(user, "soem", TimeoutClient)
    assert user.rig.pid == pid and user.rig.proc.poll() is None
