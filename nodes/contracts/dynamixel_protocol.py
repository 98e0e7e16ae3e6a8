"""Dynamixel Protocol 1.0 and the AX-12A control table: what the actuator and the emulator share.

Instruction and error-bit codes, the control table (address -> name, size, access, range,
default), packet builders and the checksum. Public names: the constants below, ``checksum``,
``status_packet``, ``instruction_packet``, ``decode_error``.
"""

from __future__ import annotations

from collections.abc import Iterable

INST_PING, INST_READ, INST_WRITE, INST_REG_WRITE, INST_ACTION, INST_RESET = (
    0x01,
    0x02,
    0x03,
    0x04,
    0x05,
    0x06,
)
INST_SYNC_WRITE, INST_BULK_READ = 0x83, 0x92
INSTRUCTION_NAMES = {
    INST_PING: "PING",
    INST_READ: "READ",
    INST_WRITE: "WRITE",
    INST_REG_WRITE: "REG_WRITE",
    INST_ACTION: "ACTION",
    INST_RESET: "RESET",
    INST_SYNC_WRITE: "SYNC_WRITE",
    INST_BULK_READ: "BULK_READ",
}
BROADCAST_ID = 0xFE
ERR_VOLTAGE, ERR_ANGLE, ERR_OVERHEAT, ERR_RANGE, ERR_CHECKSUM, ERR_OVERLOAD, ERR_INSTRUCTION = (
    1,
    2,
    4,
    8,
    16,
    32,
    64,
)
ERROR_WORDS = {
    ERR_VOLTAGE: "input voltage error",
    ERR_ANGLE: "angle limit error",
    ERR_OVERHEAT: "overheating error",
    ERR_RANGE: "range error",
    ERR_CHECKSUM: "checksum error",
    ERR_OVERLOAD: "overload error",
    ERR_INSTRUCTION: "instruction error",
}

# AX-12A control table: address -> (name, size, writable, min, max, default). None default =
# dynamic.
CONTROL_TABLE: dict[int, tuple[str, int, bool, int, int, int | None]] = {
    0: ("model_number", 2, False, 0, 65535, 12),
    2: ("firmware_version", 1, False, 0, 255, 24),
    3: ("id", 1, True, 0, 253, 1),
    4: ("baud_rate", 1, True, 0, 254, 1),
    5: ("return_delay_time", 1, True, 0, 254, 250),
    6: ("cw_angle_limit", 2, True, 0, 1023, 0),
    8: ("ccw_angle_limit", 2, True, 0, 1023, 1023),
    11: ("temperature_limit", 1, True, 0, 150, 70),
    12: ("min_voltage_limit", 1, True, 50, 250, 60),
    13: ("max_voltage_limit", 1, True, 50, 250, 140),
    14: ("max_torque", 2, True, 0, 1023, 1023),
    16: ("status_return_level", 1, True, 0, 2, 2),
    17: ("alarm_led", 1, True, 0, 127, 36),
    18: ("shutdown", 1, True, 0, 127, 36),
    24: ("torque_enable", 1, True, 0, 1, 0),
    25: ("led", 1, True, 0, 1, 0),
    26: ("cw_compliance_margin", 1, True, 0, 255, 1),
    27: ("ccw_compliance_margin", 1, True, 0, 255, 1),
    28: ("cw_compliance_slope", 1, True, 0, 254, 32),
    29: ("ccw_compliance_slope", 1, True, 0, 254, 32),
    30: ("goal_position", 2, True, 0, 1023, None),
    32: ("moving_speed", 2, True, 0, 1023, 0),
    34: ("torque_limit", 2, True, 0, 1023, 1023),
    36: ("present_position", 2, False, 0, 1023, None),
    38: ("present_speed", 2, False, 0, 2047, 0),
    40: ("present_load", 2, False, 0, 2047, 0),
    42: ("present_voltage", 1, False, 0, 255, 120),
    43: ("present_temperature", 1, False, 0, 255, 32),
    44: ("registered", 1, False, 0, 1, 0),
    46: ("moving", 1, False, 0, 1, 0),
    47: ("lock", 1, True, 0, 1, 0),
    48: ("punch", 2, True, 32, 1023, 32),
}
TABLE_SIZE = 50
ADDR = {v[0]: k for k, v in CONTROL_TABLE.items()}
EEPROM_END = 24
UNITS_PER_DEG = 1023.0 / 300.0
SPEED_RPM_PER_UNIT = 0.111
MAX_RPM = 59.0  # AX-12A no-load speed at 12 V; moving speed 0 = "maximum" = this


def checksum(body: Iterable[int]) -> int:
    """Protocol 1.0 checksum of the bytes after the 0xFF 0xFF header (id, length, ...)."""
    return (~sum(body)) & 0xFF


def status_packet(dxl_id: int, error: int, params: bytes = b"") -> bytes:
    """A Protocol 1.0 status packet: FF FF id len error params checksum."""
    body = bytes([dxl_id, len(params) + 2, error]) + bytes(params)
    return b"\xff\xff" + body + bytes([checksum(body)])


def instruction_packet(dxl_id: int, instruction: int, params: bytes = b"") -> bytes:
    """A Protocol 1.0 instruction packet (for tests and tools that speak to the emulator
    directly)."""
    body = bytes([dxl_id, len(params) + 2, instruction]) + bytes(params)
    return b"\xff\xff" + body + bytes([checksum(body)])


def decode_error(error: int) -> list[str]:
    """Words for the error bits of a Protocol 1.0 status packet."""
    return [w for bit, w in ERROR_WORDS.items() if error & bit]
