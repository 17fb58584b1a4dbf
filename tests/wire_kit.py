"""The one veth-namespace kit of the wire tests (EtherCAT over a veth pair, pysoem/KickCAT in a namespace).

Every test package that puts a master on a veth pair uses these two (gatewaylab/ethercat/wire_netns.py):
``net_capable()`` says why a test must
skip (not Linux, no iproute2, no CAP_NET_ADMIN/CAP_NET_RAW, a master library missing) and
``veth_namespace()`` makes a namespace with the master's end of a fresh veth pair in it, and removes both
again, whatever the test did. Importable from every test folder (tests/ is on sys.path through
tests/conftest.py).
"""

from __future__ import annotations

from gatewaylab.ethercat.wire_netns import net_unavailable, veth_namespace

__all__ = ["lost_allowed", "net_capable", "veth_namespace"]


def net_capable(*modules: str) -> str | None:
    """None when this process may create namespaces and raw sockets (and can import ``modules``), else the
    reason to skip."""
    return net_unavailable(*modules)


def lost_allowed(cycles: int) -> int:
    """Lost frames a cyclic wire test tolerates (2 %, at least 1), counted and printed, never hidden.

    A lost cycle -- no reply within the master's default timeout: SOEM's EC_NOFRAME, a KickCAT timeout --
    is what a real line may do and every master handles; on this shared VM the emulator drops a frame it
    could only answer late (``[ethercat] max_residence_ms``) and the kernel itself can hold a veth frame
    for milliseconds (a vCPU not scheduled). A wrong answer -- a reply with a wrong working counter, wrong
    data, a wrong state -- is never tolerated. docs/decisions.md says why the line is drawn here.
    """
    return max(1, cycles // 50)
