"""Our SDO server answers the benchmark's request frames as CiA 301 says, byte for byte as
python-canopen's LocalNode does (benchmarks/bench_canopen_sdo.py times exactly these transfers on
both servers, so the comparison is of the same work).

Manual: CiA 301 7.2.4.3.3-7.2.4.3.7 (initiate download/upload, download/upload segment) and the
command bytes of figures 21-25; IDX Communication Guide 3.3.3.2 (SDO object).
"""

from __future__ import annotations

import pytest

from benchmarks.bench_canopen_sdo import TEXT, TRANSFERS, LocalServer, OurServer

_T = TEXT.encode()
_RX = 0x585     # 0x580 + node-id 5
#: CiA 301: the server's answer to each request of each transfer.
EXPECTED: dict[str, list[bytes]] = {
    # scs 2, n 0, e 1, s 1: 0x43, the mux, 4 data bytes little-endian
    "expedited upload": [bytes.fromhex("4300200078563412")],
    # scs 3: 0x60, the mux, 4 reserved zero bytes
    "expedited download": [bytes.fromhex("6001200000000000")],
    # scs 2, s 1, e 0: 0x41 with the size 20; then upload segment responses t=0, t=1 and t=0 n=1 c=1
    "segmented upload": [bytes.fromhex("4102200014000000"), b"\x00" + _T[0:7], b"\x10" + _T[7:14],
                         b"\x03" + _T[14:20] + b"\x00"],
    # scs 3: 0x60; then download segment responses scs 1 with the toggle of the request
    "segmented download": [bytes.fromhex("6002200000000000"), bytes.fromhex("2000000000000000"),
                           bytes.fromhex("3000000000000000"), bytes.fromhex("2000000000000000")],
}


@pytest.mark.parametrize("name", list(TRANSFERS))
def test_answers_match_cia301_and_localnode(name: str) -> None:
    """CiA 301 7.2.4.3.3-7: each request frame gets one answer on 0x580 + node-id; the same
    objects give the same bytes on both servers, run after run (the transfers leave them as they
    were)."""
    ours, local = OurServer(), LocalServer()
    expected = [(_RX, data) for data in EXPECTED[name]]
    for _ in range(2):
        assert ours.answers(TRANSFERS[name]) == expected
        assert local.answers(TRANSFERS[name]) == expected
