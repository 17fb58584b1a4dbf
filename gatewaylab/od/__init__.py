"""The one object dictionary of gatewaylab: types and codecs, rows, hooks, SDO aborts, EDS/ESI.

Below ``canopen/`` and ``ethercat/`` in the layering: it imports only ``common/``. A CANopen node
and an EtherCAT slave's CoE server both keep their objects in an :class:`ObjectDictionary`; each
protocol brings its state-dependent :class:`AccessPolicy`.
"""

from gatewaylab.od.aborts import SdoAbort, SdoAbortCode, abort_text
from gatewaylab.od.dictionary import AccessPolicy, Key, Listener, ObjectDictionary, ReadHook, Validator, WriteHook
from gatewaylab.od.types import (
    BYTES_TYPES,
    ESI_TYPE_NAMES,
    FLOAT_TYPES,
    INT_TYPES,
    SIZED_TYPES,
    STRING_TYPES,
    UNDECLARED_STRING_LENGTH,
    Access,
    DataType,
    Entry,
    KeyObject,
    ObjectCode,
    OdObject,
    check_length,
    check_limits,
    coerce,
    decode,
    encode,
    key_object,
    type_default,
    type_range,
    type_size,
)

__all__ = [
    "BYTES_TYPES", "ESI_TYPE_NAMES", "FLOAT_TYPES", "INT_TYPES", "SIZED_TYPES", "STRING_TYPES",
    "UNDECLARED_STRING_LENGTH", "Access", "AccessPolicy", "DataType", "Entry", "Key", "KeyObject", "Listener",
    "ObjectCode", "ObjectDictionary", "OdObject", "ReadHook", "SdoAbort", "SdoAbortCode", "Validator", "WriteHook",
    "abort_text", "check_length", "check_limits", "coerce", "decode", "encode", "key_object", "type_default",
    "type_range", "type_size",
]
