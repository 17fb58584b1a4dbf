"""Rig files from outside: whatever a decoded TOML document holds, only ConfigError comes out
(DEVELOPERS.md 'Every parser: ... a hypothesis property test that only spec errors come out';
issue 15 'Property tests (hypothesis) on every decoder that reads bytes from outside: ... rig files')."""

from __future__ import annotations

from typing import Any

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gatewaylab.common.errors import ConfigError
from gatewaylab.rig.config import parse_rig
from gatewaylab.rig.runtime import Rig

KEYS = ["clock", "rig", "bus", "drive", "device", "ethercat", "name", "bitrate", "data_bitrate", "timing",
        "endpoint", "tcp_port", "kind", "node_id", "serial", "usb", "pty", "latency_ms", "interface", "cpu",
        "maxon_idx", "ethercat_io", "store", "revision", "sdo_timeout", "segment_size", "colour"]
WORDS = ["can0", "can1", "simulated", "realtime", "unix", "none", "drive", "maxon_idx", "ethercat_io",
         "ethercat", "x", ""]

scalars = st.one_of(st.integers(-2, 2**33), st.sampled_from([0, 1, 2, 127, 128, 0x1002, 10_000, 1_000_000]),
                    st.floats(allow_nan=True), st.booleans(), st.sampled_from(WORDS))
values = st.recursive(scalars, lambda inner: st.one_of(
    st.lists(inner, max_size=3), st.dictionaries(st.sampled_from(KEYS), inner, max_size=5)), max_leaves=12)
documents = st.dictionaries(st.sampled_from(KEYS), values, max_size=5)
# documents that get past the first checks more often: real section shapes with random contents
shaped = st.fixed_dictionaries({
    "clock": st.just("simulated"),
    "bus": st.lists(st.dictionaries(st.sampled_from(KEYS), scalars, max_size=4).map(lambda d: {"name": "can0", **d}),
                    max_size=2),
    "drive": st.lists(st.dictionaries(st.sampled_from(KEYS), scalars, max_size=5), max_size=3),
    "device": st.lists(st.dictionaries(st.sampled_from(KEYS), values, max_size=5), max_size=3),
})


def _check(data: dict[str, Any]) -> None:
    try:
        config = parse_rig(data, "fuzz.toml")
    except ConfigError as exc:
        assert "\n" not in str(exc)
        return
    if config.clock == "simulated" and config.ethercat is None:
        try:
            Rig(config, endpoints=False).close()
        except ConfigError as exc:
            assert "\n" not in str(exc)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(documents)
def test_random_documents_give_only_config_errors(data: dict[str, Any]) -> None:
    """Any decoded document: a RigConfig or one ConfigError line, never another exception."""
    _check(data)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(shaped)
def test_section_shaped_documents_give_only_config_errors(data: dict[str, Any]) -> None:
    """Sections with random keys and values: a rig (built and closed) or one ConfigError line."""
    _check(data)
