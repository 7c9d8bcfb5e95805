"""After a stop, a command ends the processes it started before it ends itself
(:func:`datt.runs.stop_children`): a child that stops on SIGTERM gets it, one that ignores it is
killed, and the services that end with the command (wandb's, torch's compile workers, resource
trackers) are left to their owners. Each case runs in its own parent process, so the
test runner's own children (compile workers) are never touched."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import pytest

# the parent: starts the children described by argv[1] (a JSON list of {"ignore_term": bool,
# "tag": str, "save_s": seconds a SIGTERM takes to save}), waits until each runs, calls
# stop_children and prints {"termed", "children", "alive_after", "said": what each printed}
PARENT = textwrap.dedent(
    """
    import json, os, signal, subprocess, sys, time
    from datt.runs import stop_children

    CHILD = (
        "import signal, sys, time\\n"
        "def saved(*_):\\n"
        "    time.sleep(float(sys.argv[3]))\\n"
        "    print('saved', flush=True)\\n"
        "    sys.exit(0)\\n"
        "signal.signal(signal.SIGTERM, signal.SIG_IGN if sys.argv[1] == 'ignore' else saved)\\n"
        "print('ready', flush=True)\\n"
        "time.sleep(600)\\n"
    )
    procs = []
    for spec in json.loads(sys.argv[1]):
        mode = "ignore" if spec["ignore_term"] else "stop"
        save_s = str(spec.get("save_s", 0.0))
        cmd = [sys.executable, "-c", CHILD, mode, spec["tag"], save_s]
        p = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
        assert p.stdout.readline().strip() == "ready"
        procs.append(p)
    termed = stop_children(grace_s=0.0, stop_s=float(sys.argv[2]))
    alive = [p.pid for p in procs if p.poll() is None]
    for p in procs:  # the test's own cleanup of what stop_children rightly left
        p.kill()
    said = [p.stdout.read().split() for p in procs]  # what each printed after "ready"
    out = {"termed": termed, "children": [p.pid for p in procs], "alive_after": alive, "said": said}
    print(json.dumps(out))
    """
)


def run_parent(children: list[dict], stop_s: float = 30.0) -> dict:
    out = subprocess.run(
        [sys.executable, "-c", PARENT, json.dumps(children), str(stop_s)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 0, out.stderr[-2000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_children_that_stop_on_sigterm_get_it_and_are_gone():
    got = run_parent([{"ignore_term": False, "tag": "job-a"}, {"ignore_term": False, "tag": "job-b"}])
    assert sorted(got["termed"]) == sorted(got["children"])
    assert got["alive_after"] == []
    assert got["said"] == [["saved"], ["saved"]]  # each ended on the SIGTERM, not on a SIGKILL


def test_a_child_gets_the_time_it_needs_to_save():
    """A job that takes a second to save after the SIGTERM saves (is not killed half way)."""
    got = run_parent([{"ignore_term": False, "tag": "slow-saver", "save_s": 1.0}])
    assert got["said"] == [["saved"]] and got["alive_after"] == []


def test_a_child_that_ignores_sigterm_is_killed_after_the_wait():
    got = run_parent([{"ignore_term": True, "tag": "stubborn"}], stop_s=0.5)
    assert got["termed"] == got["children"]
    assert got["alive_after"] == [] and got["said"] == [[]]


@pytest.mark.parametrize("service", ["wandb-core", "torch/_inductor/compile_worker/__main__.py", "resource_tracker"])
def test_a_service_that_ends_with_the_command_is_left_to_its_owner(service):
    got = run_parent([{"ignore_term": False, "tag": service}, {"ignore_term": False, "tag": "job"}])
    kept, job = got["children"]
    assert got["termed"] == [job]
    assert got["alive_after"] == [kept]
