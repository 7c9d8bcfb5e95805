"""CRTP packet layouts shared by the simulated Crazyflie and the golden-byte tests (no cflib).

A CRTP packet is one header byte ``port << 4 | 0b11 << 2 | channel`` and up to 30 data bytes;
over UDP one packet is one datagram (cflib's ``udpdriver``). Layouts follow the Crazyflie
firmware and cflib (protocol version 12):

* commander (port 3, ch 0), legacy RPYT setpoint: ``<fffH`` roll, pitch (negated by cflib on the
  wire), yaw rate, thrust. With the ``flightmode.stabModeRoll/Pitch = 0`` parameters the
  firmware reads roll/pitch as rates; all three in deg/s.
* localization (port 6, ch 0), external position: ``<fff`` x, y, z in m.
* supervisor (port 9, ch 1): arm ``(1, do_arm)``, emergency stop ``(3,)``; replies set bit 7.
* log (port 5): TOC on ch 0 (info ``(3,)`` -> ``<BHI`` + limits; item ``(2, id)`` ->
  ``(2, id, type, group\\0name\\0)``), settings on ch 1, data on ch 2 ``(block, ts[3], values)``.
* param (port 2): the same TOC layout on ch 0, read ch 1 ``<H`` -> ``<HB`` + value, write ch 2.
"""

from __future__ import annotations

import struct

PORT_PARAM, PORT_COMMANDER, PORT_MEM, PORT_LOG, PORT_LOCALIZATION = 2, 3, 4, 5, 6
PORT_COMMANDER_GENERIC, PORT_SUPERVISOR, PORT_PLATFORM, PORT_LINK = 7, 9, 13, 15
LOG_TYPES = {"uint8_t": (0x01, "<B"), "uint16_t": (0x02, "<H"), "float": (0x07, "<f")}
PARAM_TYPES = {"uint8_t": (0x08, "<B"), "uint16_t": (0x09, "<H"), "uint32_t": (0x0A, "<I"), "float": (0x06, "<f")}
MAX_LOG_BLOCK_BYTES = 26  # 30-byte payload minus block id and 3-byte timestamp


def header(port: int, channel: int) -> int:
    return ((port & 0x0F) << 4) | (0x3 << 2) | (channel & 0x03)


def split(datagram: bytes) -> tuple[int, int, bytes]:
    """(port, channel, data) of one received datagram."""
    h = datagram[0]
    return (h >> 4) & 0x0F, h & 0x03, datagram[1:]


def packet(port: int, channel: int, data: bytes | bytearray | tuple = b"") -> bytes:
    return bytes([header(port, channel)]) + bytes(data)


def rpyt_setpoint(roll: float, pitch_wire: float, yaw_rate: float, thrust: int) -> bytes:
    """Legacy commander packet as cflib's ``send_setpoint`` builds it (``pitch_wire`` is already
    the negated pitch cflib puts on the wire)."""
    return packet(PORT_COMMANDER, 0, struct.pack("<fffH", roll, pitch_wire, yaw_rate, thrust))


def extpos(x: float, y: float, z: float) -> bytes:
    return packet(PORT_LOCALIZATION, 0, struct.pack("<fff", x, y, z))


def toc_info(port: int, count: int, crc: int) -> bytes:
    return packet(port, 0, struct.pack("<BHIBB", 3, count, crc, 16, 128))


def toc_item(port: int, ident: int, type_id: int, group: str, name: str) -> bytes:
    return packet(port, 0, struct.pack("<BHB", 2, ident, type_id) + group.encode() + b"\0" + name.encode() + b"\0")


def log_data(block: int, timestamp_ms: int, payload: bytes) -> bytes:
    ts = timestamp_ms & 0xFFFFFF
    return packet(PORT_LOG, 2, bytes([block, ts & 0xFF, (ts >> 8) & 0xFF, (ts >> 16) & 0xFF]) + payload)
