"""The persistent master's counters (ec_server.py): ``gatewaylab ec master --master SOCKET`` printed the
*expected* working counter as the 'last working counter' (the cycle kept the second item of
``exchange()``'s (working counter, expected)), so a line with a missing slave looked healthy. IgH's
``ethercat domains`` shows both, current/expected; so do the server's counters now."""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

from gatewaylab.cli.ec_server import EcMasterServer, request


class ShortLine:
    """A backend whose line answers 5 of the 6 expected working counter increments (a slave missing)."""

    wkc_errors = 0

    def slaves(self) -> list[Any]:
        return []

    def exchange(self) -> tuple[int, int]:
        self.wkc_errors += 1
        return 5, 6


def test_last_working_counter_is_the_current_one_not_the_expected(tmp_path: Path) -> None:
    sock = tmp_path / "ec.sock"

    def no_verbs(_backend: Any, _verb: str, _args: dict[str, Any]) -> tuple[int, str, str]:
        return 2, "", ""

    server = EcMasterServer(ShortLine(), sock, no_verbs, cycle=0.001)  # type: ignore[arg-type]
    server.mapped = True
    up = threading.Event()
    thread = threading.Thread(target=server.serve, args=(up.set,))
    thread.start()
    try:
        assert up.wait(30)
        info = request(str(sock), {"info": True})
        for _ in range(3000):          # until the cycle thread exchanged once (bounded, no sleep)
            if info["exchanges"]:
                break
            info = request(str(sock), {"info": True})
        assert info["exchanges"] > 0
        assert info["working_counter"] == 5
        assert server.last_expected == 6
    finally:
        request(str(sock), {"stop": True})
        thread.join(30)
    assert not thread.is_alive()
