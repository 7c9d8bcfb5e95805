"""How a flight ended: a kind and its detail, one text for the log, one exit status for the command.

The kinds (:class:`Kind`) and what ``deploy.py`` exits with:

* ``landed``, ``landed_early`` (a LAND decision: the detail says why), ``landed_onboard``: 0;
* ``refused_setting``: a setting refused the flight before arming (the detail names the key): 2;
* ``refused_reference``: the vehicle took off and hovered, but the reference asks for more thrust
  than its measured ceiling (``datt.deploy.feasibility``): it landed without tracking: 2;
* ``refused`` (a preflight check failed), ``arming_failed``, ``killed``, ``link_lost``,
  ``incomplete``: 4 (a lost link is the vehicle's or the radio's failure, not the user's);
* ``stopped``: a stop signal before arming, nothing armed: 130.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum


class Kind(str, Enum):
    LANDED = "landed"
    LANDED_EARLY = "landed_early"
    LANDED_ONBOARD = "landed_onboard"
    REFUSED_SETTING = "refused_setting"
    REFUSED_REFERENCE = "refused_reference"
    REFUSED = "refused"
    ARMING_FAILED = "arming_failed"
    STOPPED = "stopped"
    KILLED = "killed"
    LINK_LOST = "link_lost"
    INCOMPLETE = "incomplete"


_TEXT = {
    Kind.LANDED: "landed",
    Kind.LANDED_EARLY: "landed early: {}",
    Kind.LANDED_ONBOARD: "landed (onboard)",
    Kind.REFUSED_SETTING: "preflight failed: {}",
    Kind.REFUSED_REFERENCE: "landed without tracking: {}",
    Kind.REFUSED: "preflight failed: {}",
    Kind.ARMING_FAILED: "arming failed: {}",
    Kind.STOPPED: "stopped before arming ({}): nothing was armed",
    Kind.KILLED: "killed: {}",
    Kind.LINK_LOST: "link lost: {}",
    Kind.INCOMPLETE: "incomplete",
}
_EXIT = {
    Kind.LANDED: 0,
    Kind.LANDED_EARLY: 0,
    Kind.LANDED_ONBOARD: 0,
    Kind.REFUSED_SETTING: 2,
    Kind.REFUSED_REFERENCE: 2,
    Kind.STOPPED: 130,
}


@dataclass(frozen=True)
class Outcome:
    kind: Kind
    detail: str = ""

    @property
    def text(self) -> str:
        return _TEXT[self.kind].format(self.detail)

    @property
    def landed(self) -> bool:
        return self.kind in (Kind.LANDED, Kind.LANDED_EARLY, Kind.LANDED_ONBOARD)

    @property
    def exit_code(self) -> int:
        return _EXIT.get(self.kind, 4)

    def __str__(self) -> str:
        return self.text
