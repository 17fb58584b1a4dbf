"""The pytest fixture's errors (docs/testing-your-master.md): a mistake in the rig a test gives
``gatewaylab_rig`` is one ConfigError naming the user's key -- on the simulated clock, in process and in a
`gatewaylab run` child alike -- and the user's rig (the dict as "rig dict", or the user's file), never a
temporary rig.toml the fixture wrote, and never a start that "timed out" when nothing did."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from gatewaylab.common.errors import ConfigError
from gatewaylab.rig.process import RigProcess, RigStartTimeout

WRONG_KEY = {"bus": [{"name": "can0", "bitrat": 500_000}]}
SAYS = "rig dict [[bus]] #1 (can0): unknown keys ['bitrat'] (allowed: "


@pytest.mark.parametrize("how", [{"clock": "realtime"}, {"clock": "realtime", "in_process": True},
                                 {"clock": "simulated"}])
def test_a_wrong_key_in_a_rig_dict_is_one_config_error_on_every_clock(gatewaylab_rig: Any,
                                                                      how: dict[str, Any]) -> None:
    with pytest.raises(ConfigError) as caught:
        gatewaylab_rig(WRONG_KEY, **how)
    message = str(caught.value)
    assert not isinstance(caught.value, RigStartTimeout)
    assert message.startswith(SAYS) and "rig.toml" not in message and "\n" not in message


@pytest.mark.parametrize("clock", ["realtime", "simulated"])
def test_a_wrong_key_in_a_rig_file_names_the_users_file(gatewaylab_rig: Any, tmp_path: Path, clock: str) -> None:
    rig = tmp_path / "my-rig.toml"
    rig.write_text('[[bus]]\nname = "can0"\nbitrat = 500000\n')
    with pytest.raises(ConfigError, match=r"my-rig.toml \[\[bus\]\] #1 \(can0\): unknown keys \['bitrat'\]"):
        gatewaylab_rig(rig, clock=clock)


def test_a_child_that_refuses_its_rig_file_raises_config_error_not_a_timeout(tmp_path: Path) -> None:
    """RigProcess: `gatewaylab run` exiting 2 (docs/cli.md: the rig file is wrong) is a ConfigError with
    the child's one line, not RigStartTimeout ("did not start")."""
    rig = tmp_path / "bad.toml"
    rig.write_text('[[bus]]\nname = "can0"\nbitrat = 500000\n')
    with pytest.raises(ConfigError) as caught:
        RigProcess(rig, workdir=tmp_path, timeout=60)
    assert not isinstance(caught.value, RigStartTimeout)
    assert str(caught.value).startswith(f"{rig} [[bus]] #1 (can0): unknown keys ['bitrat']")
