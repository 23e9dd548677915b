"""The wire protocol between the modules (LRMs) and the ship: one home for both sides.

ZeroMQ DEALER (module) to ROUTER (ship) over TCP. Every message is a
multipart message of one UTF-8 JSON header and at most one binary payload.
``docs/protocol.md`` describes it for someone writing a module in another
language, ``docs/protocol-v1.schema.json`` is its JSON Schema (generated
from `camcal.core.wire.models`); this package is the reference implementation.
JSON headers and raw bytes only: never pickle.

* `dialect`: the JSON dialect (limits on numbers and depth, no NaN);
* `models`: every message as a strict model;
* `sensors`: the sensor columns, their units and ranges;
* `image`: what a frame payload's first bytes say it is;
* `reasons`: why a message is refused (``nack``), and whether to resend;
* `codec`: `encode` and `decode` (and `decode` in two halves: `decode_header`, then `check_payload`
  in steps);
* `sensorrows`: a sensor payload checked in steps, its rows as an array;
* `keys`: the link's CURVE keys (ship and modules) and their folder;
* `sockets`: the ship's and a module's socket (CURVE with keys);
* `schema`: the JSON Schema of the protocol.
"""

from camcal.core.wire.codec import (
    ADAPTER,
    Message,
    ProtocolError,
    check_payload,
    content_sha256,
    decode,
    decode_header,
    encode,
    message_ref,
    parse_sensor_rows,
    sensors_payload,
    sha256_hex,
)
from camcal.core.wire.keys import KeyFileError, KeyPair, ModuleKeys, module_keys, ship_pair
from camcal.core.wire.limits import MAX_HEADER_BYTES, MAX_PAYLOAD_BYTES, MAX_SENSOR_ROWS
from camcal.core.wire.models import (
    DATA_TYPES,
    MODULE_TYPES,
    PROTOCOL_VERSION,
    SHIP_TYPES,
    Ack,
    Bye,
    CameraInfo,
    Command,
    CommandStatus,
    FrameMsg,
    Hello,
    ModuleHeartbeat,
    Nack,
    ScheduleState,
    SensorsMsg,
    ShipHeartbeat,
    SimulatedClock,
    Waiting,
    Welcome,
    is_id,
    utc_now,
)
from camcal.core.wire.reasons import REASONS, Reason
from camcal.core.wire.sensors import SENSOR_COLUMNS, SENSOR_SPEC
from camcal.core.wire.sockets import module_socket, ship_socket

__all__ = [
    "ADAPTER",
    "DATA_TYPES",
    "MAX_HEADER_BYTES",
    "MAX_PAYLOAD_BYTES",
    "MAX_SENSOR_ROWS",
    "MODULE_TYPES",
    "PROTOCOL_VERSION",
    "REASONS",
    "SENSOR_COLUMNS",
    "SENSOR_SPEC",
    "SHIP_TYPES",
    "Ack",
    "Bye",
    "CameraInfo",
    "Command",
    "CommandStatus",
    "FrameMsg",
    "Hello",
    "KeyFileError",
    "KeyPair",
    "Message",
    "ModuleHeartbeat",
    "ModuleKeys",
    "Nack",
    "ProtocolError",
    "Reason",
    "ScheduleState",
    "SensorsMsg",
    "ShipHeartbeat",
    "SimulatedClock",
    "Waiting",
    "Welcome",
    "check_payload",
    "content_sha256",
    "decode",
    "decode_header",
    "encode",
    "is_id",
    "message_ref",
    "module_keys",
    "module_socket",
    "parse_sensor_rows",
    "sensors_payload",
    "sha256_hex",
    "ship_pair",
    "ship_socket",
    "utc_now",
]
