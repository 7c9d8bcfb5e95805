"""The host's side of the onboard DATT app (``deploy.onboard=true``; the app: ``datt export
format=app``, docs/onboard.md): its parameters, log variables, phases and the reference upload
over the app channel. The packet layout and the phase numbers are those of ``datt_onboard.h``
(a test reads them from the header)."""

from __future__ import annotations

import struct
import threading

from datt.deploy.clock import WALL
from datt.deploy.firmware import APP_CHANNEL_RX_QUEUE

PKT_POINTS, PKT_ACK = 0x01, 0x81
ACK_OK, ACK_RANGE, ACK_BUSY, ACK_MALFORMED = 0, 1, 2, 3
POINTS_PER_PACKET = 2  # 4 + 2 * 12 bytes: within the app channel's 30
TABLE_MAX = 1024  # DATT_TABLE_MAX of the app as exported
IDLE, TRACK, LAND, DONE, ABORTED, REFUSED = range(6)
READ_ONLY = ("policyId", "controllerId")  # PARAM_RONLY in app_datt.c

# (name, C type, datt_onboard_params field, index or None): the app's parameter group "datt"
PARAMS = [
    ("run", "uint8_t", None, None),
    ("policyId", "uint32_t", None, None),  # read-only: DATT_POLICY_ID of the policy compiled in
    ("controllerId", "uint8_t", None, None),  # read-only: ControllerTypeOot of the firmware it was built in
    ("originX", "float", "origin_m", 0),
    ("originY", "float", "origin_m", 1),
    ("originZ", "float", "origin_m", 2),
    ("nPoints", "uint16_t", "n_points", None),
    ("trackSteps", "uint16_t", "track_steps", None),
    ("landZ", "float", "land_z_m", None),
    ("landS", "float", "land_s", None),
    ("landHoldS", "float", "land_hold_s", None),
    ("hoverCmd", "float", "hover_command", None),
    ("slope", "float", "slope_mps2_per_command", None),
    ("maxCmd", "uint16_t", "max_command", None),
    ("maxRateRoll", "float", "max_rate_degps", 0),
    ("maxRatePitch", "float", "max_rate_degps", 1),
    ("maxRateYaw", "float", "max_rate_degps", 2),
    ("maxTiltDeg", "float", "max_tilt_deg", None),
    ("maxPosStdM", "float", "max_pos_std_m", None),
]
# the app's log group "datt": what the host follows in flight (one block: 19 bytes)
LOG_BLOCK = ["datt.phase", "datt.step", "datt.errM", "datt.refX", "datt.refY", "datt.refZ"]
LOGS = [  # (name, C type)
    ("phase", "uint8_t"),
    ("step", "uint16_t"),
    ("nRx", "uint16_t"),
    ("errM", "float"),
    ("refX", "float"),
    ("refY", "float"),
    ("refZ", "float"),
    ("selfTest", "uint8_t"),
    ("landedEarly", "uint8_t"),
]


def points_packet(index: int, points) -> bytes:
    """One upload packet: points ``index .. index + len(points) - 1`` (controller frame, m)."""
    flat = [float(v) for p in points for v in p]
    return struct.pack(f"<BHB{len(flat)}f", PKT_POINTS, index, len(points), *flat)


def parse_ack(data: bytes) -> tuple[int, int] | None:
    """(index, status) of an acknowledgement, None for any other packet."""
    if len(data) >= 4 and data[0] == PKT_ACK:
        return data[1] | (data[2] << 8), data[3]
    return None


class Upload:
    """Sends a reference table and waits for every packet's acknowledgement; a packet not
    acknowledged within ``timeout_s`` is sent again (at most ``attempts`` times in all)."""

    def __init__(self, send, table, timeout_s: float = 0.1, attempts: int = 10, clock=WALL) -> None:
        if len(table) > TABLE_MAX:
            raise ValueError(f"the reference has {len(table)} points; the app holds at most {TABLE_MAX}")
        self.send, self.table = send, [tuple(float(v) for v in p) for p in table]
        self.timeout_s, self.attempts = timeout_s, attempts
        self.pending = {i: 0 for i in range(0, len(self.table), POINTS_PER_PACKET)}  # index -> sends
        self.errors: list[str] = []
        self._lock = threading.Lock()
        self.clock = clock  # the flight's (datt.deploy.clock)
        self._answered = clock.event()  # an acknowledgement (or a refusal) arrived

    def on_packet(self, data: bytes) -> None:
        ack = parse_ack(bytes(data))
        if ack is None:
            return
        index, status = ack
        with self._lock:
            if status == ACK_OK:
                self.pending.pop(index, None)
            elif index in self.pending:
                self.errors.append(f"point {index}: the app answered status {status}")
        self._answered.set()

    def run(self, window: int = APP_CHANNEL_RX_QUEUE) -> None:
        """Send ``window`` packets, wait for their acknowledgements (or ``timeout_s``), repeat;
        raises RuntimeError when a packet stays unacknowledged or is refused. The firmware queues
        at most :data:`APP_CHANNEL_RX_QUEUE` incoming app-channel packets and drops the rest, so
        a window never exceeds it."""
        if not 1 <= window <= APP_CHANNEL_RX_QUEUE:
            raise ValueError(f"upload window {window}: the app channel queues 1..{APP_CHANNEL_RX_QUEUE} packets")
        while True:
            with self._lock:
                if self.errors:
                    raise RuntimeError("; ".join(self.errors))
                chunk = sorted(self.pending)[:window]
                if not chunk:
                    return
                for index in chunk:
                    if self.pending[index] >= self.attempts:
                        raise RuntimeError(f"point {index}: no acknowledgement after {self.attempts} sends")
                    self.pending[index] += 1
            for index in chunk:
                self.send(points_packet(index, self.table[index : index + POINTS_PER_PACKET]))
            deadline = self.clock.monotonic() + self.timeout_s
            while self.clock.monotonic() < deadline:
                self._answered.clear()
                with self._lock:
                    if self.errors or not any(i in self.pending for i in chunk):
                        break
                self.clock.wait(self._answered, deadline - self.clock.monotonic())
