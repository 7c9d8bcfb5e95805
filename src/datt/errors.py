"""User-facing error types of every layer (imports nothing of the project).

A :class:`ConfigError` is a user mistake: the entry points print it as one line
(``error: <key>: <what>``) and exit with status 2, never with a traceback.
"""

from __future__ import annotations


class ConfigError(ValueError):
    """A user-facing configuration error (one line that names the key and, where there is a
    fixed set, the allowed values)."""


class TrainingDiverged(RuntimeError):
    """A NaN/inf appeared in the loss, observations or actions (raised by ``datt.train.ppo``)."""


class TrainingInterrupted(RuntimeError):
    """SIGINT/SIGTERM (or a scheduler's preemption signal) during training: the checkpoint is saved;
    the message says where and how to resume (the entry points exit with 130, or hand a preemption
    signal back to the scheduler, which requeues the job). ``signal``: the signal's name."""

    def __init__(self, message: str, signal: str | None = None) -> None:
        super().__init__(message)
        self.signal = signal


class FlightAborted(RuntimeError):
    """A flight that did not end in a landing (KILLed, refused before arming, link lost); the log
    is written. The entry points exit with 4."""


class FlightStopped(RuntimeError):
    """A stop signal before arming: the flight ended with nothing armed; the log is written. The
    entry points exit with 130."""


class LinkError(RuntimeError):
    """The radio link to the vehicle failed: it could not connect, or the vehicle did not answer
    or refused a setting (``datt.deploy.link``)."""


def one_line(exc: BaseException) -> str:
    """Collapse an exception (and Hydra/OmegaConf wrappers) to its innermost one-line message."""
    while exc.__cause__ is not None:
        exc = exc.__cause__
    msg = str(exc).strip().splitlines()
    return msg[0] if msg else type(exc).__name__
