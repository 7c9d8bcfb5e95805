"""The runner's mocap forwarding thread (``FlightRunner._forward_frames``) on its own: each frame
goes to the vehicle once, as it arrives; a wake-up without a frame, a repeat or a stale frame is
skipped and the thread carries on (a dead forwarder would leave the Kalman filter without mocap)."""

import threading
import time

import pytest

from datt.deploy.runner import FlightRunner
from datt.deploy.safety import SafetyParams


class RecordingLink:
    """What the vehicle was sent (the radio link's two mocap calls)."""

    def __init__(self) -> None:
        self.sent: list[tuple] = []

    def send_extpos(self, pos) -> None:
        self.sent.append(("extpos", tuple(pos)))

    def send_extpose(self, pos, quat) -> None:
        self.sent.append(("extpose", tuple(pos), tuple(quat)))


def forwarding_runner() -> tuple[FlightRunner, threading.Thread]:
    # only the forwarder's own state: the thread reads nothing else of the runner
    runner = object.__new__(FlightRunner)
    runner.link, runner.safety = RecordingLink(), SafetyParams()
    runner._mocap_sent_t, runner._pending_frame = None, None
    runner._frame_lock, runner._frame_ready = threading.Lock(), threading.Event()
    runner._forwarding, runner._lead = True, None
    thread = threading.Thread(target=runner._forward_frames, daemon=True)
    thread.start()
    return runner, thread


def sent_after(runner: FlightRunner, count: int, timeout_s: float = 2.0) -> list[tuple]:
    deadline = time.monotonic() + timeout_s
    while len(runner.link.sent) < count and time.monotonic() < deadline:
        time.sleep(0.005)
    time.sleep(0.06)  # one more wait period: nothing else may follow
    return runner.link.sent


def test_each_frame_goes_out_once_and_a_wake_up_without_a_frame_is_skipped():
    runner, thread = forwarding_runner()
    try:
        runner._frame_ready.set()  # woken, but the frame was already taken
        time.sleep(0.1)
        assert thread.is_alive() and runner.link.sent == []
        t = time.monotonic()
        runner._forward_frame(((1.0, 2.0, 3.0), None, t))
        assert sent_after(runner, 1) == [("extpos", (1.0, 2.0, 3.0))]
        runner._forward_frame(((1.0, 2.0, 3.0), None, t))  # the same frame again: not resent
        assert sent_after(runner, 2) == [("extpos", (1.0, 2.0, 3.0))]  # (taken alone, not overwritten)
        runner._forward_frame(((0.0, 0.0, 1.0), None, time.monotonic() - 1.0))  # stale (1 s old)
        assert sent_after(runner, 2) == [("extpos", (1.0, 2.0, 3.0))]
        runner._forward_frame(((4.0, 5.0, 6.0), (1.0, 0.0, 0.0, 0.0), time.monotonic()))
        assert sent_after(runner, 2)[-1] == ("extpose", (4.0, 5.0, 6.0), (1.0, 0.0, 0.0, 0.0))
        assert thread.is_alive()
    finally:
        runner._forwarding = False
        thread.join(1.0)
    assert not thread.is_alive()


def test_with_a_lead_the_vehicle_is_sent_the_led_position_and_the_frames_own_attitude():
    from datt.deploy.mocap import FrameLead

    runner, thread = forwarding_runner()
    runner._lead = FrameLead(0.03, 0.04)
    try:
        t = time.monotonic()
        runner._forward_frame(((0.0, 0.0, 1.0), (1.0, 0.0, 0.0, 0.0), t - 0.01))  # 1 m/s along x
        sent_after(runner, 1)
        runner._forward_frame(((0.01, 0.0, 1.0), (1.0, 0.0, 0.0, 0.0), t))
        kind, pos, quat = sent_after(runner, 2)[-1]
        assert kind == "extpose" and quat == (1.0, 0.0, 0.0, 0.0)
        assert pos[0] == pytest.approx(0.01 + 0.03) and pos[1:] == (0.0, 1.0)
    finally:
        runner._forwarding = False
        thread.join(1.0)
