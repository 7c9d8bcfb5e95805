"""``torch.compile`` with a safe fallback: if compilation fails on first use (no C++ compiler,
unsupported platform), warn once and run the eager function instead of failing the run."""

from __future__ import annotations

import warnings
from collections.abc import Callable

import torch


def compile_or_eager(fn: Callable, **kwargs) -> Callable:
    compiled = torch.compile(fn, dynamic=False, **kwargs)
    state = {"impl": compiled}

    def call(*args):
        try:
            return state["impl"](*args)
        except Exception as exc:  # inductor/backend errors surface on the first call
            if state["impl"] is fn:
                raise
            warnings.warn(f"torch.compile failed for {fn.__name__} ({type(exc).__name__}); running eager", stacklevel=2)
            state["impl"] = fn
            return fn(*args)

    call.__name__ = f"compiled_{fn.__name__}"
    return call
