"""CAN status (0xF108, mappable through 0x1A85) and statistics (0x2010) on the in-process master
(manual 5.1.3.9, 5.1.4.2, 5.1.5.8), the SM watchdog count, handler times on the clock."""

from __future__ import annotations

import struct
from typing import Any

import pytest

from gatewaylab.bus.frame import CanFrame
from gatewaylab.devices.esd_can_ethercat.objects import esd_description
from gatewaylab.ethercat.errors import AlStatusCode, FrameFormatError
from gatewaylab.ethercat.esc import AlState
from gatewaylab.ethercat.mailbox import MBX_ERROR, MailboxErrorCode, MailboxType
from gatewaylab.ethercat.sii import build_sii, parse_sii
from gatewaylab.od import SdoAbort, SdoAbortCode


def _assign_status_pdo(kit: Any) -> None:
    m = kit.master
    kit.preop()
    m.sdo_download8(0, 0x1C13, 0, 0)
    m.sdo_download16(0, 0x1C13, 2, 0x1A85)
    m.sdo_download8(0, 0x1C13, 0, 2)


def test_status_pdo_1a85_carries_bus_off_and_error_counters(kit: Any) -> None:
    """4.2 '(The optional PDO 0x1a85 contains CAN Status information)': assigned after 0x1A00 it adds
    6 bytes: byte 0 bit 0 Bus OFF, bit 1 Warning limit, bit 2 Rx overflow; byte 4 REC, byte 5 TEC
    (5.1.3.9 paddings); values from the controller (5.1.5.8)."""
    _assign_status_pdo(kit)
    kit.op()
    assert kit.in_size == 168 + 6
    kit.cycle()
    assert kit.master.pdo_read(0, 168, 6) == bytes(6)
    kit.bus.force_bus_off(kit.gw.controller)
    kit.cycle()
    status = kit.master.pdo_read(0, 168, 6)
    assert status[0] & 0x03 == 0x03 and status[5] == 255
    assert kit.master.sdo_upload8(0, 0xF108, 1) == 1
    kit.cycle(5)                                      # auto recovery after 128 x 11 recessive bits
    assert kit.master.pdo_read(0, 168, 6) == bytes(6)


def test_status_pdo_shows_the_receive_error_counter_and_rx_overflow(kit: Any) -> None:
    """5.1.5.8 'Rx error counter (Read from CAN controller Rx error counter byte)' at a wrong bit
    rate, and 'Rx overflow' after a local queue overrun."""
    kit.bus.attach("other")
    _assign_status_pdo(kit)
    kit.master.sdo_download16(0, 0x8000, 0x23, 1)
    kit.op(baud_index=3)
    for i in range(7):
        kit.peer.send(CanFrame(0x100 + i, b"x"))
    kit.cycle(5)
    assert kit.master.pdo_read(0, 168 + 4, 1) == b"\x07"
    kit.gw.controller.bitrate = 500_000               # the bus is fixed: the rate matches again
    for i in range(4):
        kit.peer.send(CanFrame(0x200 + i, b"y"))
    kit.cycle(5)
    status = kit.master.pdo_read(0, 168, 6)
    assert status[0] & 0x04 and status[4] == 3        # REC counts down with every good frame


def test_statistics_count_every_frame_kind_and_reset_on_write(kit: Any) -> None:
    """5.1.4.2: Tx requested / Tx / Rx, driver counters per frame kind (standard/extended, data/RTR);
    writing 'Reset' zeroes them and reading it shows the reset time in ms since start-up."""
    m = kit.master
    kit.preop()
    m.sdo_download16(0, 0x8000, 0x20, 1)
    kit.op()
    kit.send([CanFrame(0x1, b"a"), CanFrame(0x2, rtr=True, dlc=1), CanFrame(0x3, b"b", extended=True),
              CanFrame(0x4, extended=True, rtr=True, dlc=2), CanFrame(0x5, b"c")])
    kit.cycle(5)
    for f in (CanFrame(0x10, b"12"), CanFrame(0x11, rtr=True), CanFrame(0x12, b"3", extended=True),
              CanFrame(0x13, b"4", extended=True), CanFrame(0x14, extended=True, rtr=True)):
        kit.peer.send(f)
    kit.receive_all()
    counts = {sub: m.sdo_upload32(0, 0x2010, sub) for sub in range(0x30, 0x40) if sub != 0x33}
    assert counts == {0x30: 5, 0x31: 5, 0x32: 5, 0x34: 0, 0x35: 0, 0x36: 0, 0x37: 0,
                      0x38: 1, 0x39: 1, 0x3A: 2, 0x3B: 1, 0x3C: 2, 0x3D: 1, 0x3E: 1, 0x3F: 1}
    kit.clock.advance(1.5)
    m.sdo_download32(0, 0x2010, 1, 0)
    assert all(m.sdo_upload32(0, 0x2010, sub) == 0 for sub in range(0x30, 0x40) if sub != 0x33)
    assert m.sdo_upload32(0, 0x2010, 1) == round(1000 * kit.clock.now())


def test_sm_watchdog_falls_back_and_is_counted(kit: Any) -> None:
    """5.1.4.2 'Watchdog triggered: times application watchdog was triggered due to missing process
    data (watchdog value from ESC registers 0x0400 and 0x0420)': SAFEOP + 0x001B, counted in 0x2010:08;
    after the master brings it back the handshake goes on."""
    m = kit.master
    kit.op()
    kit.send([CanFrame(0x1, b"a")])
    kit.clock.advance(0.5)                          # no process data for 500 ms (watchdog 100 ms)
    status, code = m.al_status(0)
    assert status == AlState.SAFEOP | 0x10 and code == AlStatusCode.SM_WATCHDOG
    assert m.sdo_upload32(0, 0x2010, 8) == 1
    m.request_state(0, AlState.SAFEOP, ack=True)
    m.request_state(0, AlState.OP)
    kit.send([CanFrame(0x2, b"b")], first_tn=2)
    kit.cycle(3)
    assert kit.heard == [CanFrame(0x1, b"a"), CanFrame(0x2, b"b")] and kit.inputs()[3] == 2
    kit.clock.advance(0.5)
    assert m.sdo_upload32(0, 0x2010, 8) == 2


class _TickingClock:
    """The kit's clock, but every now() also moves 7 us on: handler times become visible."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner
        self.extra = 0.0
        self.step = 7e-6

    def now(self) -> float:
        self.extra += self.step
        return float(self.inner.now()) + self.extra

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)


def test_cyclic_and_can_handler_times_are_measured_on_the_clock(kit: Any) -> None:
    """5.1.4.2 'Cyclic handler time' / 'CAN handler time' (min, max, avg in us): the time the clock
    says each handler took."""
    kit.op()
    kit.gw.clock = _TickingClock(kit.clock)
    kit.cycle(3)
    kit.peer.send(CanFrame(0x5, b"x"))
    kit.cycle(3)
    m = kit.master
    cyc = [m.sdo_upload32(0, 0x2010, s) for s in (2, 3, 4)]
    can = [m.sdo_upload32(0, 0x2010, s) for s in (5, 6, 7)]
    assert cyc[0] >= 6 and cyc[0] <= cyc[2] <= cyc[1]
    assert can[0] >= 6 and can[0] <= can[2] <= can[1]


def test_can_handler_time_forgets_calls_older_than_the_last_1000(kit: Any) -> None:
    """5.1.4.2 'CAN handler time (max.)': 'Maximum time in application's CAN handler within its last
    1000 calls': one slow call shows, and is gone after 1000 quick ones."""
    kit.op()
    clock = _TickingClock(kit.clock)
    kit.gw.clock = clock
    clock.step = 500e-6
    kit.peer.send(CanFrame(0x5, b"x"))
    kit.clock.advance(0.01)
    clock.step = 7e-6
    m = kit.master
    assert m.sdo_upload32(0, 0x2010, 6) >= 400
    for i in range(999):
        kit.peer.send(CanFrame(0x6, bytes([i & 0xFF])))
    kit.clock.advance(1.0)
    assert m.sdo_upload32(0, 0x2010, 6) >= 400          # the slow call is one of the last 1000
    kit.peer.send(CanFrame(0x7, b"y"))
    kit.clock.advance(0.01)
    assert m.sdo_upload32(0, 0x2010, 6) < 100


def test_other_settings_2000_local_mode_in_preop_only_and_led_state_as_written(kit: Any) -> None:
    """5.1.4.1 NOTICE 'can only be written in Pre-Operational state: Index 2000h, Sub-Index 1';
    'Custom LED state ... Reading this value reflects only the value that was last written'."""
    m = kit.master
    kit.preop()
    m.sdo_download8(0, 0x2000, 1, 1)
    m.sdo_download8(0, 0x2000, 2, 13)                # 13: Blink
    kit.op()
    assert (m.sdo_upload8(0, 0x2000, 1), m.sdo_upload8(0, 0x2000, 2)) == (1, 13)
    with pytest.raises(SdoAbort) as err:
        m.sdo_download8(0, 0x2000, 1, 0)
    assert err.value.code == SdoAbortCode.DATA_CANNOT_BE_STORED_DEVICE_STATE
    m.sdo_download8(0, 0x2000, 2, 15)                # 15: On, in any state
    assert (m.sdo_upload8(0, 0x2000, 1), m.sdo_upload8(0, 0x2000, 2)) == (1, 15)


def test_no_eoe_offered_an_eoe_request_gets_the_mailbox_error_and_2010_eoe_counts_stay_0(kit: Any) -> None:
    """5.2 EoE and 5.1.4.2 'EoE Frames ...' (2010h:10-16) are not emulated (docs/decisions.md): the
    SII offers CoE and FoE only (so a master set up from this ESI sends no EoE; 5.2.1 'usually
    configuration tools don't send a configuration' in the default Switch Port mode either); an EoE
    'Set IP Parameter' request gets the mailbox error 'unsupported protocol' (ETG.1000.4), the
    gateway goes on, and the EoE counters read 0."""
    assert parse_sii(build_sii(esd_description())).mailbox_protocols == 0x0C     # CoE | FoE, no EoE (0x02)
    m = kit.master
    kit.preop()
    set_ip = struct.pack("<HHI", 0x0002, 0, 0x0E) + bytes([192, 168, 0, 10, 255, 255, 255, 0, 192, 168, 0, 1])
    with pytest.raises(FrameFormatError) as err:
        m.mailbox_exchange(0, MailboxType.EOE, set_ip)
    assert str(err.value).endswith(MBX_ERROR.pack(0x0001, MailboxErrorCode.UNSUPPORTED_PROTOCOL).hex())
    kit.op()
    kit.send([CanFrame(0x1, b"a")])
    kit.cycle(3)
    assert kit.heard == [CanFrame(0x1, b"a")]
    assert [m.sdo_upload32(0, 0x2010, sub) for sub in range(0x10, 0x17)] == [0] * 7
