"""The motion-capture client in a process of its own: ``python -m datt.deploy.mocap_stream
<system> <json settings> <body>`` prints one JSON line per frame that holds ``body``
(``{"p": [x, y, z], "q": [w, x, y, z] | null}``), and ``{"bodies": [...]}`` for frames without it.

Why a process: a vendor SDK behind ``motioncapture`` can block in its connect or frame wait at full
CPU without returning to the interpreter (an unreachable Vicon or OptiTrack host); in the flying
process that ignored SIGINT and SIGTERM. Here the host process keeps its signals, waits for the
first frame with a deadline (:class:`datt.deploy.mocap.MotionCaptureMocap`) and kills this one.
"""

from __future__ import annotations

import json
import sys


def main(argv: list[str]) -> int:
    import motioncapture

    system, settings, body = argv[0], json.loads(argv[1]), argv[2]
    try:
        mc = motioncapture.connect(system, settings)
    except RuntimeError as exc:  # the library's own refusal (unknown system, no answer)
        print(json.dumps({"error": str(exc)}), flush=True)
        return 1
    while True:
        mc.waitForNextFrame()
        bodies = mc.rigidBodies
        obj = bodies.get(body)
        if obj is None:
            print(json.dumps({"bodies": sorted(bodies)}), flush=True)
            continue
        q = getattr(obj, "rotation", None)
        quat = None if q is None else [float(q.w), float(q.x), float(q.y), float(q.z)]
        print(json.dumps({"p": [float(v) for v in obj.position], "q": quat}), flush=True)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
