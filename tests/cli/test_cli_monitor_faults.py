"""`gatewaylab monitor` shows the active EtherCAT faults (the "faults" of the rig's ethercat-states answer,
docs/faults.md "EtherCAT faults"): one event when a fault appears, one when it is gone."""

from __future__ import annotations

from gatewaylab.cli.monitor_faults import FaultWatch, describe_fault

LOSE = {"id": 3, "fault": "ec-lose", "target": "segment", "replies": False, "cmd": ["LRW"], "hits": 0, "left": 2}
DELAY = {"id": 4, "fault": "ec-delay", "target": "segment", "us": 3000, "jitter": 0, "seed": 1, "hits": 9,
         "ends_at": 12.5}


def test_a_fault_starting_and_ending_is_one_event_each() -> None:
    """Seen, still there (progress only: no event), gone."""
    watch = FaultWatch()
    first = watch.changes([LOSE], 1.0)
    assert [e.text for e in first] == ["EtherCAT fault #3 active: ec-lose on segment (replies=False, cmd=LRW), 2 left"]
    assert first[0].fields["fault_state"] == "active" and first[0].kind == "ethercat"
    assert watch.changes([{**LOSE, "left": 1}, DELAY], 1.5)[0].text.startswith("EtherCAT fault #4 active: ec-delay")
    gone = watch.changes([DELAY], 2.0)
    assert [e.text for e in gone] == ["EtherCAT fault #3 ended: ec-lose on segment"]
    assert [e.text for e in watch.changes(None, 2.5)] == ["EtherCAT fault #4 ended: ec-delay on segment"]


def test_describe_names_the_end_time() -> None:
    """A fault with a duration says until when (the rig's clock)."""
    assert describe_fault(DELAY) == "ec-delay on segment (us=3000, jitter=0, seed=1), until t=12.500 s"
