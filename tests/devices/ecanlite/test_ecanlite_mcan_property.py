"""Random SDO writes to every ecan-mcan object: only SDO aborts or status codes, never a crash
(ECAN-Lite manual 13: 'bad input gets the spec's error', DEVELOPERS.md principle 4)."""

from __future__ import annotations

from ecanlite_mcan_kit import make_rig
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gatewaylab.bus import CanFrame
from gatewaylab.od import SdoAbort, SdoAbortCode

_RIG = make_rig(channels=2)
_KEYS = sorted(k for k in _RIG.od.entries if k[0] >= 0x8000 and k[1] != 0)

#: Commands and keys, drawn more often than plain settings.
_COMMANDS = [(0x8001, 1), (0x8001, 3), (0x8001, 45), (0x8001, 46), (0x8002, 1), (0x8021, 2), (0x8022, 2),
             (0xB000, 1), (0xB000, 4), (0xA000, 2), (0xA001, 2), (0x8020, 2), (0x8030, 1), (0x8000, 12)]
writes = st.lists(st.tuples(st.one_of(st.sampled_from(_KEYS), st.sampled_from(_COMMANDS)),
                            st.one_of(st.integers(0, 0xFFFFFFFF), st.sampled_from([0, 1, 2, 3, 7, 8, 64, 0xFF])),
                            st.integers(0, 5)), max_size=25)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(writes)
def test_random_writes_only_aborts(ops: list[tuple[tuple[int, int], int, int]]) -> None:
    """Every write either stores or raises SdoAbort with a known code; reads of every status object
    still work afterwards and the channels still carry frames or report a TX result code."""
    rig = make_rig(channels=2)
    for (index, sub), value, extra in ops:
        entry = rig.od.entry(index, sub)
        size = max(1, entry.bit_length // 8)
        data = (value & ((1 << 8 * size) - 1)).to_bytes(size, "little")
        if extra == 5:
            data = data + b"\x00"          # wrong length
        try:
            rig.od.write(index, sub, data)
        except SdoAbort as exc:
            assert SdoAbortCode.known(exc.code)
        rig.run(0.001)
    for index in (0x8001, 0x8002, 0x8021, 0x9000, 0x9001, 0x9020, 0xA000, 0xB000, 0xF000):
        for sub in rig.od.objects[index].entries:
            try:
                rig.od.read(index, sub)
            except SdoAbort as exc:
                assert exc.code == SdoAbortCode.WRITE_ONLY
    for ch in rig.model.channels[:2]:
        code = ch.submit(CanFrame(0x123, b"\x01"), "p")
        assert code in range(6)
        ch.status_word()
        ch.peek(8)
    rig.run(0.05)
    for ch in rig.model.channels[:2]:
        assert all(result in range(6) for _ref, result in ch.take_tx_results())
