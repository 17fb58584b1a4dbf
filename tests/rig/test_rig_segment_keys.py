"""The ``[ethercat]`` keys of the wire's timing (docs/rig.md "The [ethercat] keys"): their defaults and ranges,
checked like every rig key before anything is built."""

from __future__ import annotations

import pytest

from gatewaylab.common.errors import ConfigError
from gatewaylab.rig.segment import SEGMENT_KIND


def test_defaults_reply_on_time_realtime_short_switch_interval() -> None:
    """docs/rig.md: max_residence_ms 2.0 (the masters' default receive timeouts), realtime true,
    switch_interval_us 200."""
    cfg = SEGMENT_KIND.validate({"interface": "gl-ecat"}, "[ethercat]")
    assert cfg["max_residence_ms"] == 2.0
    assert cfg["realtime"] is True
    assert cfg["switch_interval_us"] == 200.0


def test_zero_turns_the_limits_off_and_an_int_is_a_number() -> None:
    """``max_residence_ms = 0``: no limit; ``switch_interval_us = 0``: the interpreter's interval is left alone."""
    cfg = SEGMENT_KIND.validate({"interface": "gl-ecat", "max_residence_ms": 0, "switch_interval_us": 0,
                                 "realtime": False}, "[ethercat]")
    assert cfg["max_residence_ms"] == 0 and cfg["switch_interval_us"] == 0 and cfg["realtime"] is False


@pytest.mark.parametrize(("key", "value"), [("max_residence_ms", -1.0), ("switch_interval_us", -5.0),
                                            ("switch_interval_us", 10_000.0), ("realtime", "yes"),
                                            ("max_residence_ms", "2 ms")])
def test_out_of_range_or_wrong_type_is_one_config_error_line(key: str, value: object) -> None:
    """docs/rig.md 'Every section is checked before anything is created': one line naming the key."""
    with pytest.raises(ConfigError) as err:
        SEGMENT_KIND.validate({"interface": "gl-ecat", key: value}, "rig.toml [ethercat]")
    assert key in str(err.value) and "\n" not in str(err.value)
