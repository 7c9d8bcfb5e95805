"""The lockstep clock (datt.deploy.clock): virtual time moves only when every thread taking part
waits on it and nothing handed between threads is on its way, then to the earliest deadline.
Every assertion is on virtual time; real time only bounds a join (a hang guard)."""

import threading

import pytest

from datt.deploy.clock import WALL, LockstepClock

HANG_GUARD_S = 60.0  # a join's bound: a broken clock fails the test instead of hanging it


def _run(clock, *targets):
    clock.take_part()  # the test's thread starts them all before time can move
    threads = [clock.start_thread(t, f"t{i}") for i, t in enumerate(targets)]
    clock.leave()  # and waits outside the clock
    for t in threads:
        t.join(HANG_GUARD_S)
        assert not t.is_alive(), "a thread of the clock never finished"


def test_sleepers_wake_in_deadline_order_at_exactly_their_deadlines():
    clock = LockstepClock(start_s=10.0)
    woke = []

    def sleeper(seconds):
        def run():
            clock.sleep(seconds)
            woke.append((seconds, clock.monotonic()))

        return run

    _run(clock, sleeper(0.3), sleeper(0.1), sleeper(0.2))
    assert woke == [(0.1, 10.1), (0.2, 10.2), (0.3, 10.3)]


def test_time_waits_for_a_thread_that_is_running():
    clock = LockstepClock(start_s=0.0, stall_s=1e9)
    release, seen = threading.Event(), {}

    def busy():  # blocks outside the clock: to the clock it is computing
        release.wait(HANG_GUARD_S)
        seen["busy_saw"] = clock.monotonic()

    def sleeper():
        clock.sleep(0.5)
        seen["sleeper_woke"] = clock.monotonic()

    clock.take_part()
    threads = [clock.start_thread(busy, "busy"), clock.start_thread(sleeper, "sleeper")]
    release.set()
    clock.leave()
    for t in threads:
        t.join(HANG_GUARD_S)
    assert seen == {"busy_saw": 0.0, "sleeper_woke": 0.5}


def test_time_waits_for_what_is_on_its_way_between_threads():
    clock = LockstepClock(start_s=0.0, stall_s=1e9)
    release, seen = threading.Event(), {}
    clock.begin()  # a datagram sent, not yet taken up

    def sleeper():
        clock.sleep(0.5)
        seen["woke"] = clock.monotonic()

    clock.take_part()
    thread = clock.start_thread(sleeper, "sleeper")
    clock.leave()

    def receiver():  # not a thread of the clock: it only takes the datagram up
        release.wait(HANG_GUARD_S)
        seen["taken_up_at"] = clock.monotonic()
        clock.end()

    plain = threading.Thread(target=receiver)
    plain.start()
    release.set()
    plain.join(HANG_GUARD_S)
    thread.join(HANG_GUARD_S)
    assert seen == {"taken_up_at": 0.0, "woke": 0.5}


def test_an_event_set_by_another_thread_ends_the_wait_at_the_setters_time():
    clock = LockstepClock(start_s=0.0)
    event, seen = clock.event(), {}

    def waiter():
        seen["got"] = clock.wait(event, 5.0)
        seen["at"] = clock.monotonic()

    def setter():
        clock.sleep(0.2)
        event.set()

    _run(clock, waiter, setter)
    assert seen == {"got": True, "at": 0.2}


def test_a_wait_whose_event_never_comes_ends_at_its_deadline():
    clock = LockstepClock(start_s=0.0)
    event, seen = clock.event(), {}

    def waiter():
        seen["got"] = clock.wait(event, 0.7)
        seen["at"] = clock.monotonic()

    _run(clock, waiter)
    assert seen == {"got": False, "at": 0.7}


def test_a_thread_wedged_outside_the_clock_does_not_hang_the_others():
    """The stall guard: a send that never returns still meets its caller's timeout."""
    clock = LockstepClock(start_s=0.0, stall_s=0.1)
    wedged, seen = threading.Event(), {}
    clock.start_thread(lambda: wedged.wait(), "wedged")  # runs (to the clock) until the test ends

    def waiter():
        seen["got"] = clock.wait(clock.event(), 0.2)

    _run(clock, waiter)
    wedged.set()
    assert seen == {"got": False}
    assert clock.stalls >= 1


def test_the_wall_clock_is_real_time():
    event = WALL.event()
    event.set()
    assert WALL.wait(event, 0.0) is True
    assert not WALL.lockstep and LockstepClock().lockstep


@pytest.mark.parametrize("clock_name", ["real_time", "lockstep", "other"])
def test_the_simulated_vehicle_takes_only_the_clocks_it_has(clock_name):
    from datt.deploy.sim.server import check_server_settings
    from datt.errors import ConfigError

    if clock_name == "other":
        with pytest.raises(ConfigError, match=r"deploy.server.clock.*real_time.*lockstep"):
            check_server_settings({"clock": clock_name})
    else:
        check_server_settings({"clock": clock_name})


@pytest.mark.flight
def test_a_flight_on_the_lockstep_clock_lands_and_no_tick_is_late(tmp_path):
    """The simulated vehicle and the host on one virtual clock: the default flight lands, and its
    ticks are exactly on schedule (the host's compute takes no virtual time)."""
    from tests.deploy import fly_sim, ports

    summary, server, _ = fly_sim(tmp_path, next(ports), ["deploy.server.clock=lockstep"])
    assert server.clock.lockstep
    assert summary["outcome"] == "landed", summary["outcome"]
    assert summary["late_ticks"] == 0 and summary["jitter_ms"]["max"] == 0.0
