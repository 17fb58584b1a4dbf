"""`gatewaylab fault drive-fault NAME` / `rig.faults.drive_fault` reaches the EtherCAT drive (issue 16: "CoE emergency
messages for drive faults ... `gatewaylab fault` (when it exists) reaches this drive too")."""

from pathlib import Path

from gatewaylab.ethercat.esc import AlState
from gatewaylab.ethercat.segment import Segment
from gatewaylab.hosts.ethercat.master import Master
from gatewaylab.rig.config import parse_rig
from gatewaylab.rig.runtime import Rig


def test_rig_fault_is_a_coe_emergency_and_0x603f(tmp_path: Path) -> None:
    """ETG.6010 / CiA 402: a following error (0x8611) injected through the rig's fault API puts the drive in
    fault reaction, writes 0x603F and sends a CoE emergency the master reads from the mailbox (ETG.1000.6)."""
    config = parse_rig({"clock": "simulated", "bus": [{"name": "can0", "endpoint": "none"}],
                        "device": [{"kind": "ethercat_drive", "name": "ax1"}]})
    rig = Rig(config, state_dir=tmp_path, endpoints=False)
    try:
        (participant,) = rig.participants
        master = Master(rig.clock, Segment([participant.slave]))   # type: ignore[attr-defined]
        master.bring_up()
        assert AlState(master.al_status(0)[0] & 0x0F) is AlState.OP
        answer = rig.faults.drive_fault("ax1", "following-error")
        assert answer["error_code"] == 0x8611
        code, register, _ = master.receive_emergency(0)
        assert code == 0x8611 and register == 0x21   # CiA 301 0x1001: generic error + device profile bit
        assert master.sdo_upload16(0, 0x603F, 0) == 0x8611
    finally:
        rig.close()
