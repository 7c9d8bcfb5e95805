"""The test processes' UDP ports for simulated Crazyflies (``tests/deploy/__init__.py``)."""

from __future__ import annotations

import os
import socket

from . import _free_ports, ports


def test_a_port_another_socket_holds_is_skipped():
    """Two test processes side by side (xdist workers, mutmut's forked children) must never be
    handed the same port while one of them holds it: the second vehicle could not bind and its
    test would fail for a reason that is not the code's."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as held:
        held.bind(("127.0.0.1", 0))
        port = held.getsockname()[1]
        drawn = _free_ports(port)
        assert next(drawn) > port
    assert next(_free_ports(port)) == port  # released: free again


def test_a_forked_process_draws_from_its_own_start():
    """The counter's start is fixed by the process that draws: a child forked after the parent
    drew starts at its own place (its process id's), not where the parent's counter stands."""
    from . import _WORKER

    next(ports)  # the parent draws first
    read, write = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: report its first port and leave at once
        os.write(write, str(next(ports)).encode())
        os._exit(0)
    os.waitpid(pid, 0)
    child_first = int(os.read(read, 16))
    os.close(read)
    os.close(write)
    start = 19900 + 500 * _WORKER + 20 * (pid % 20)
    assert child_first == next(_free_ports(start))
