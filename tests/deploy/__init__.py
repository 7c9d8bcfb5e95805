"""Deploy tests. ``SHORT_FLIGHT``: the shortened flight every flying test uses."""

SHORT_FLIGHT = [
    "deploy.flight.takeoff_s=1.5",
    "deploy.flight.hover_s=0.5",
    "deploy.flight.track_s=3.0",
    "deploy.flight.land_s=1.5",
    # a loaded CI machine stalls the server's threads for up to ~0.5 s (seen: 0.47 s); the
    # default 0.1 s would KILL. The mocap limit stays at 0.4 s: after a dropout the onboard
    # estimate drifts, and 0.8 s of chasing it once tilted past the 75 deg KILL limit.
    "deploy.safety.max_state_age_s=0.8",
    "deploy.safety.kill_state_age_s=1.0",
    "deploy.safety.max_mocap_age_s=0.4",
]
