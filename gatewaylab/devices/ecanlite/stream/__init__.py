"""The ECAN-Lite frame-stream PDO codec (manual chapters 6-11, 13.2, 13.8): the one copy of the format.

Both PDO directions carry the same image of ``128*N`` bytes (5.2): a 24-byte little-endian fixed
header (chapter 6) and, from offset 24, a stream of packets (chapter 8): CAN_FRAME (KIND 0) and,
in the TxPDO only, TX_RESULT (KIND 1, chapter 10). The device parses the RxPDO and builds the
TxPDO with this package; the host library does the opposite with the same functions. One concept
per module: :mod:`.format` (constants, enums, shared functions, errors), :mod:`.layout` (a
direction's active profile and what it allows), :mod:`.packets` (header and packet records),
:mod:`.encode` and :mod:`.decode`. Choices the manual leaves open are listed in docs/decisions.md
under "ECAN-Lite frame stream".
"""

from gatewaylab.devices.ecanlite.stream.decode import commit_state, decode_stream
from gatewaylab.devices.ecanlite.stream.encode import encode_into, encode_stream, packet_size
from gatewaylab.devices.ecanlite.stream.format import (
    CRC_ALG_CCITT_FALSE,
    DEFAULT_FEATURES,
    HEADER_SIZE,
    MAX_CHANNELS,
    MAX_FRAME_COUNT,
    OPTION_MASK,
    PROFILE_MASK,
    TIMESTAMP_UNIT_S,
    VER_IHL,
    Commit,
    Direction,
    Feature,
    HeaderFlags,
    Option,
    PacketKind,
    ParseDiag,
    PdoError,
    ProfileStatus,
    StreamEncodeError,
    StreamError,
    Tsf,
    TxResultCode,
    check_layout,
    check_options,
    crc16,
    dlc_to_len,
    fold_layout_id,
    next_seq,
    profile_word,
    saturate_u8,
    timestamp_ticks,
)
from gatewaylab.devices.ecanlite.stream.layout import StreamLayout
from gatewaylab.devices.ecanlite.stream.packets import (
    CanPacket,
    DecodedStream,
    Packet,
    StreamHeader,
    TxResultPacket,
)

__all__ = [
    "CRC_ALG_CCITT_FALSE", "DEFAULT_FEATURES", "HEADER_SIZE", "MAX_CHANNELS", "MAX_FRAME_COUNT", "OPTION_MASK",
    "PROFILE_MASK", "TIMESTAMP_UNIT_S", "VER_IHL", "CanPacket", "Commit", "DecodedStream", "Direction", "Feature",
    "HeaderFlags", "Option", "Packet", "PacketKind", "ParseDiag", "PdoError", "ProfileStatus", "StreamEncodeError",
    "StreamError", "StreamHeader", "StreamLayout", "Tsf", "TxResultCode", "TxResultPacket", "check_layout",
    "check_options", "commit_state", "crc16", "decode_stream", "dlc_to_len", "encode_into", "encode_stream",
    "fold_layout_id", "next_seq", "packet_size", "profile_word", "saturate_u8", "timestamp_ticks",
]
