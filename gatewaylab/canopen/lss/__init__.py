"""CiA 305 Layer Setting Services: the frames, the slave and the master, each in its own module.

* :mod:`.frames` -- command specifiers, states, :class:`LssAddress`, the request/response codecs.
* :mod:`.slave` -- :class:`LssSlaveMachine` (pure: ``on_request(data) -> list[LssAction]``) and
  :class:`LssSlave`, which binds a machine to a :class:`~gatewaylab.canopen.node.Node`.
* :mod:`.master` -- :class:`LssMaster`, sans-I/O: ``LssMaster(clock, send)``, fed with ``on_frame``.

Every public name stays importable from ``gatewaylab.canopen.lss``.
"""

from gatewaylab.canopen.lss.frames import (
    BIT_TIMING_TABLE,
    FASTSCAN_CONFIRM,
    LSS_MASTER_COB_ID,
    LSS_SLAVE_COB_ID,
    UNCONFIGURED,
    Cs,
    LssAddress,
    LssState,
    bit_timing_index,
    encode_activate_bit_timing,
    encode_configure_bit_timing,
    encode_configure_node_id,
    encode_cs,
    encode_fastscan,
    encode_result,
    encode_switch_global,
    encode_u32,
)
from gatewaylab.canopen.lss.master import LssError, LssMaster, LssTimeout, ResultCallback
from gatewaylab.canopen.lss.slave import (
    ALLOWED,
    ActivateBitTiming,
    AdoptNodeId,
    LssAction,
    LssConfigStore,
    LssSlave,
    LssSlaveMachine,
    LssSlaveStats,
    Reply,
    StoreFunction,
)

__all__ = [
    "ALLOWED", "BIT_TIMING_TABLE", "FASTSCAN_CONFIRM", "LSS_MASTER_COB_ID", "LSS_SLAVE_COB_ID", "UNCONFIGURED",
    "ActivateBitTiming", "AdoptNodeId", "Cs", "LssAction", "LssAddress", "LssConfigStore", "LssError", "LssMaster",
    "LssSlave", "LssSlaveMachine", "LssSlaveStats", "LssState", "LssTimeout", "Reply", "ResultCallback",
    "StoreFunction", "bit_timing_index", "encode_activate_bit_timing", "encode_configure_bit_timing",
    "encode_configure_node_id", "encode_cs", "encode_fastscan", "encode_result", "encode_switch_global", "encode_u32",
]
