"""The DATT app inside the simulated Crazyflie: the app's own C (``datt_onboard.c`` and the
generated policy, compiled by :func:`datt.export.app.build_sil_library`) called through ctypes,
with the firmware glue of ``app_datt.c`` (its 50 Hz task body, the parameters, the log
variables) re-told here. The state it reads is the one the out-of-tree controller hook hands
over: only while ``stabilizer.controller`` selects that controller (else it stays zero, as the
hook is then never called; the task sees how old it is and refuses a stale one)."""

from __future__ import annotations

import ctypes
from pathlib import Path

from datt.deploy.onboard import IDLE, LOGS, PARAMS, READ_ONLY

_F3, _F4 = ctypes.c_float * 3, ctypes.c_float * 4


class _Params(ctypes.Structure):  # datt_onboard_params
    _fields_ = [
        ("origin_m", _F3),
        ("n_points", ctypes.c_uint16),
        ("track_steps", ctypes.c_uint16),
        ("land_z_m", ctypes.c_float),
        ("land_s", ctypes.c_float),
        ("land_hold_s", ctypes.c_float),
        ("hover_command", ctypes.c_float),
        ("slope_mps2_per_command", ctypes.c_float),
        ("max_command", ctypes.c_uint16),
        ("max_rate_degps", _F3),
        ("max_tilt_deg", ctypes.c_float),
        ("max_pos_std_m", ctypes.c_float),
    ]


class _Setpoint(ctypes.Structure):  # datt_setpoint
    _fields_ = [
        ("roll_degps", ctypes.c_float),
        ("pitch_degps", ctypes.c_float),
        ("yaw_degps", ctypes.c_float),
        ("thrust", ctypes.c_uint16),
        ("stop", ctypes.c_uint8),
        ("active", ctypes.c_uint8),
    ]


class _Status(ctypes.Structure):  # datt_onboard_status
    _fields_ = [
        ("error_m", ctypes.c_float),
        ("ref_m", _F3),
        ("d_hat", _F3),
        ("action", _F4),
        ("step", ctypes.c_uint16),
        ("n_received", ctypes.c_uint16),
        ("phase", ctypes.c_uint8),
        ("landed_early", ctypes.c_uint8),
    ]


class OnboardApp:
    """One vehicle's app: ``receive`` (app channel), ``tick`` (the task's 20 ms loop body),
    ``get``/``set`` of the ``datt.*`` parameters, ``log_values`` of the ``datt.*`` log group."""

    def __init__(self, library: str | Path, controller_id: int) -> None:
        """``controller_id``: ``ControllerTypeOot`` of the firmware the app is built into (what
        its read-only ``datt.controllerId`` holds)."""
        lib = ctypes.CDLL(str(library))
        self.controller_id = int(controller_id)
        lib.datt_onboard_state_max_age_ms.restype = ctypes.c_uint32
        self.state_max_age_s = lib.datt_onboard_state_max_age_ms() / 1000.0
        lib.datt_onboard_size.restype = ctypes.c_uint32
        lib.datt_onboard_policy_id.restype = ctypes.c_uint32
        lib.datt_onboard_params_of.restype = ctypes.POINTER(_Params)
        lib.datt_onboard_params_of.argtypes = [ctypes.c_void_p]
        for name in ("datt_onboard_init", "datt_onboard_stop", "datt_onboard_refuse"):
            getattr(lib, name).argtypes = [ctypes.c_void_p]
        lib.datt_onboard_receive.argtypes = [ctypes.c_void_p, ctypes.c_char_p, ctypes.c_int, ctypes.c_void_p]
        lib.datt_onboard_receive.restype = ctypes.c_int
        for name in ("datt_onboard_start", "datt_onboard_step"):
            getattr(lib, name).restype = ctypes.c_uint8
        lib.datt_onboard_start.argtypes = [ctypes.c_void_p, _F3, _F3, _F4]
        lib.datt_onboard_step.argtypes = [ctypes.c_void_p, _F3, _F3, _F4, ctypes.c_float, ctypes.POINTER(_Setpoint)]
        lib.datt_onboard_get_status.argtypes = [ctypes.c_void_p, ctypes.POINTER(_Status)]
        lib.datt_self_test.argtypes = [ctypes.POINTER(ctypes.c_float)]
        lib.datt_self_test.restype = ctypes.c_int
        self.lib = lib
        self._mem = ctypes.create_string_buffer(lib.datt_onboard_size())
        self.ptr = ctypes.cast(self._mem, ctypes.c_void_p)
        lib.datt_onboard_init(self.ptr)
        self.p = lib.datt_onboard_params_of(self.ptr).contents
        err = ctypes.c_float()
        self.self_test_ok = lib.datt_self_test(ctypes.byref(err)) == 0
        self.run_request = 0
        self._param_types = {name: ctype for name, ctype, _, _ in PARAMS}

    # -- the datt parameter and log groups -------------------------------------------------
    @property
    def param_toc(self) -> list[tuple]:
        return [("datt", name, ctype, self.get(name)) for name, ctype, _, _ in PARAMS]

    @property
    def log_toc(self) -> list[tuple]:
        return [("datt", name, ctype) for name, ctype in LOGS]

    def get(self, name: str) -> float:
        if name == "run":
            return self.run_request
        if name == "policyId":
            return self.lib.datt_onboard_policy_id()
        if name == "controllerId":
            return self.controller_id
        _, _, field, index = next(p for p in PARAMS if p[0] == name)
        value = getattr(self.p, field)
        return value[index] if index is not None else value

    def set(self, name: str, value: float) -> None:
        if name in READ_ONLY:
            return  # PARAM_RONLY: the firmware ignores the write
        if name == "run":
            self.run_request = int(value)
            return
        _, _, field, index = next(p for p in PARAMS if p[0] == name)
        if index is None:
            setattr(self.p, field, value)
        else:
            getattr(self.p, field)[index] = value

    def status(self) -> _Status:
        s = _Status()
        self.lib.datt_onboard_get_status(self.ptr, ctypes.byref(s))
        return s

    def log_values(self) -> list[float]:
        s = self.status()
        values = {
            "phase": s.phase,
            "step": s.step,
            "nRx": s.n_received,
            "errM": s.error_m,
            "refX": s.ref_m[0],
            "refY": s.ref_m[1],
            "refZ": s.ref_m[2],
            "selfTest": int(self.self_test_ok),
            "landedEarly": s.landed_early,
        }
        return [float(values[name]) for name, _ in LOGS]

    # -- the task ------------------------------------------------------------------------------
    def receive(self, data: bytes) -> bytes:
        reply = (ctypes.c_uint8 * 4)()
        n = self.lib.datt_onboard_receive(self.ptr, bytes(data), len(data), reply)
        return bytes(reply[:n])

    def tick(self, pos, vel, quat, pos_var_m2: float = 0.0, state_age_s: float = 0.0) -> tuple[_Setpoint | None, bool]:
        """The body of ``appMain``'s loop: start / stop on ``datt.run``, one step on the state the
        hook wrote ``state_age_s`` ago (``inf``: never) and the Kalman filter's larger horizontal
        position variance. A stale state refuses the start and pushes no setpoint. Returns the
        setpoint to push (None: none this tick) and whether the commander is handed back."""
        relax = False
        fresh = state_age_s <= self.state_max_age_s
        phase = self.status().phase
        args = (_F3(*pos), _F3(*vel), _F4(*quat))
        if self.run_request and phase == IDLE:
            if not self.self_test_ok or not fresh:
                self.lib.datt_onboard_refuse(self.ptr)
            else:
                self.lib.datt_onboard_start(self.ptr, *args)  # DATT_TRACK, or DATT_REFUSED
        elif not self.run_request and phase != IDLE:
            self.lib.datt_onboard_stop(self.ptr)
            relax = True
        if not fresh and self.status().phase != IDLE:
            return None, relax  # the commander's watchdog takes over
        sp = _Setpoint()
        self.lib.datt_onboard_step(self.ptr, *args, float(pos_var_m2), ctypes.byref(sp))
        return (sp if sp.active else None), relax

    @property
    def phase(self) -> int:
        return int(self.status().phase)
