"""End to end: the web pages of chapter 6 on the esd gateway itself (EsdGateway + its EsdWebModel
backend + EsdWebServer), driven by the in-process EtherCAT master and a peer node on the CAN bus
(the ``kit`` of tests/esd_can_ethercat/conftest.py), on a simulated clock."""

from __future__ import annotations

import html
import re
from typing import Any

from esd_web_kit import multipart, request

from gatewaylab.bus.frame import CanFrame
from gatewaylab.devices.esd_can_ethercat.web import EsdWebServer
from gatewaylab.devices.esd_can_ethercat.webmodel import EsdWebModel
from gatewaylab.ethercat.esc import AlState

IMAGE = b"CAN-EtherCAT firmware 2.4\n" + bytes(range(256)) * 16


def _can_lines(url: str) -> list[str]:
    page = request(url, "GET", "/status/can").text
    match = re.search(r'<pre id="can">\n(.*?)\n</pre>', page, re.S)
    assert match is not None
    return html.unescape(match.group(1)).splitlines()


def _info(url: str) -> dict[str, str]:
    return dict(re.findall(r"<tr><td>([^<]*)</td><td>([^<]*)</td></tr>", request(url, "GET", "/information").text))


def test_pages_follow_the_gateway_through_traffic_update_and_reboot(kit: Any) -> None:
    """6.2.1 Figure 41 with the gateway's own numbers: no bit rate at power-up (NTCAN_NO_BAUDRATE,
    5.1.5.9), then 500 kbit/s (F800:02 = 2: "0x00000002", 20 tq, 85.0 % as in the figure) and the frames
    the master sent and the peer sent counted per kind; 6.1.2 an upload through the form starts the
    update, the page shows Figure 39's output, after the update the device is back in INIT with the
    file's version; a bad file is refused with the device's reason; 6.1.3 "Reboot now" restarts it."""
    server = EsdWebServer(EsdWebModel(kit.gw), kit.clock.ensure_lock())  # as the rig runtime does
    url = server.start()
    try:
        lines = _can_lines(url)
        assert "Value set by canSetBaudrate() : 0x7fffffff" in lines
        assert "Actual Bitrate                 : 0 Bits/s" in lines

        kit.op()  # PREOP, F800:02 = 2 (500 kbit/s), mapping, SAFEOP, OP
        kit.send([CanFrame(0x10, b"abc"), CanFrame(0x11, rtr=True, dlc=2), CanFrame(0x12, bytes(8))])
        kit.peer.send(CanFrame(0x20, b"defg"))
        kit.peer.send(CanFrame(0x21, b"h"))
        kit.peer.send(CanFrame(0x22, rtr=True, dlc=0))
        assert len(kit.receive_all()) == 3
        lines = _can_lines(url)
        for line in ("Value set by canSetBaudrate() : 0x00000002",
                     "Actual Bitrate                 : 500000 Bits/s",
                     "Timequantas per Bit           : 20",
                     "Position samplepoint           : 85.0%",
                     "Rcv frames      : Std(Data/RTR): 2/1 Ext(Data/RTR) 0/0",
                     "Xmit frames     : Std(Data/RTR): 2/1 Ext(Data/RTR) 0/0",
                     "Bytes           : (Rcv/Xmit): 5/11",
                     "Err frames      : 0",
                     "Err counter     : (Rx/Tx): 0/0 Status: 00"):
            assert line in lines, line
        assert _info(url)["EtherCAT state"] == "OP"

        content_type, body = multipart("can_ethercat_2.4.bin", IMAGE)
        reply = request(url, "POST", "/firmware", body, {"Content-Type": content_type})
        assert reply.status == 303
        page = request(url, "GET", "/firmware").text
        assert "Updating now..." in page and "End of file found. All good." in page
        kit.clock.advance(kit.gw.update_duration + 0.1)
        page = request(url, "GET", "/firmware").text
        assert "Updating now..." not in page and '<input type="file"' in page
        info = _info(url)
        assert info["Firmware version"] == "2.4" and info["EtherCAT state"] == "INIT"
        assert kit.master.al_status(0)[0] == AlState.INIT

        content_type, body = multipart("empty.bin", b"")
        reply = request(url, "POST", "/firmware", body, {"Content-Type": content_type})
        assert reply.status == 400 and "Update refused: the firmware file is empty" in reply.text
        content_type, body = multipart("x.bin", b"\0")
        reply = request(url, "POST", "/firmware", body, {"Content-Type": content_type})
        assert reply.status == 303  # the device takes any non-empty file (no version line: version kept)
        kit.clock.advance(kit.gw.update_duration + 0.1)
        assert _info(url)["Firmware version"] == "2.4"

        reboots = kit.gw.reboots
        assert request(url, "POST", "/reboot", b"").status == 200
        assert kit.gw.reboots == reboots + 1
    finally:
        server.stop()
