"""``gatewaylab fault READY-FILE ec-...``: the slave family's verbs build the control requests docs/faults.md
lists (names and JSON types as ``EC_SLAVE_REQUESTS`` accepts them), and a wrong command line is exit 2."""

from __future__ import annotations

import pytest

from gatewaylab.cli.fault import build_request
from gatewaylab.cli.main import build_parser
from gatewaylab.rig.faults_ec_slave import EC_SLAVE_REQUESTS


def _request(*argv: str) -> dict[str, object]:
    return build_request(build_parser().parse_args(["fault", "ready.json", *argv]))


@pytest.mark.parametrize(("argv", "want"), [
    (("ec-al-error", "io1", "0x001D", "--on", "PS"), {"device": "io1", "code": 0x1D, "on": "PS"}),
    (("ec-al-error", "io1", "53"), {"device": "io1", "code": 53}),
    (("ec-drop-state", "io1", "safeop"), {"device": "io1", "state": "SAFEOP"}),
    (("ec-drop-state", "io1", "INIT", "--code", "0x16"), {"device": "io1", "state": "INIT", "code": 0x16}),
    (("ec-sdo-abort", "io1", "0x06020000", "--index", "0x2000", "--segment", "2"),
     {"device": "io1", "code": 0x06020000, "index": 0x2000, "segment": 2}),
    (("ec-sdo-silent", "io1"), {"device": "io1", "n": 1}),
    (("ec-sdo-silent", "io1", "-n", "3"), {"device": "io1", "n": 3}),
    (("ec-foe-error", "io1", "0x8001", "--packet", "2"), {"device": "io1", "code": 0x8001, "packet": 2}),
    (("ec-mailbox-lose", "io1"), {"device": "io1"}),
    (("ec-emcy", "io1", "0x8110", "--register", "0x11", "--data", "0102"),
     {"device": "io1", "code": 0x8110, "register": 0x11, "data": "0102"}),
    (("ec-eeprom", "io1", "product=0x1234"), {"device": "io1", "kind": "product=0x1234"}),
    (("ec-eeprom", "io1", "busy", "--seconds", "2.5"), {"device": "io1", "kind": "busy", "seconds": 2.5}),
])
def test_verbs_build_their_requests(argv: tuple[str, ...], want: dict[str, object]) -> None:
    request = _request(*argv)
    assert request == {"fault": argv[0], **want}
    _method, params = EC_SLAVE_REQUESTS[argv[0]]
    assert set(want) <= set(params)
    assert all(k in want for k, (_type, required) in params.items() if required)


@pytest.mark.parametrize("argv", [
    ("ec-foe-error", "io1", "0x8001"),                # --packet is required
    ("ec-sdo-silent", "io1", "-n", "0"),
    ("ec-drop-state", "io1", "OP"),
    ("ec-eeprom", "io1", "busy", "--seconds", "0"),
])
def test_wrong_command_lines_are_exit_2(argv: tuple[str, ...]) -> None:
    with pytest.raises(SystemExit) as exc:
        _request(*argv)
    assert exc.value.code == 2
