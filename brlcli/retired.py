"""Training knobs that the studies measured as not helping and that left the code (issue 33).

Each keeps its row, its figures and its command in the study docs; `git checkout RETIRED_AT` gives the brl that can
rerun it. A configuration that names a retired key (`--set`, `--config`, a sweep grid) is refused with one line that
says so; a saved configuration or model file of an older brl that carries a retired key at its "off" value (every
run that did not use the knob) reads as before, and one that used the knob is refused the same way.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from brlcli.errors import BrlInputError

RETIRED_AT = "5a19324"
"""The last commit with every retired knob (the study docs' commands for them run there)."""


@dataclass(frozen=True)
class Retired:
    """A retired knob: its value when it was off, and where its measurement is written up."""

    off: Any
    study: str
    commit: str = RETIRED_AT
    """A commit whose brl has the knob."""


RETIRED_CONFIG: dict[str, Retired] = {
    "teams": Retired(1, "docs/navigation-study.md section 6, rows 19-20"),
    "team_share": Retired(0.5, "docs/navigation-study.md section 6, rows 19-20"),
    "shared_mixture": Retired(False, "docs/navigation-study.md section 7"),
    "warm_start_junctions": Retired(0, "docs/navigation-study.md section 6, row 17"),
    "straight_as_follow": Retired(False, "docs/navigation-study.md section 4, row 13"),
    "no_backward": Retired(False, "docs/navigation-study.md section 6, row 18"),
    "r_heading": Retired(0.0, "docs/navigation-study.md section 5, rows 14-15"),
    "r_lateral": Retired(0.0, "docs/navigation-study.md section 5, row 14"),
    "restart_offroad_above": Retired(None, "docs/lane-keeping-study.md, row 35"),
    "keep_best": Retired(False, "docs/navigation-study.md section 4, rows 10 and 12"),
    "command_bootstrap": Retired("next-branch", "docs/navigation-study.md section 3, rows 1-7 (own-branch)"),
    "start_along_m": Retired(0.0, "docs/lane-keeping-study.md, issue 34 rows 42-43", "e446df6"),
    "gate_state": Retired("road_users", "docs/navigation-study.md section 12.6, rows gate_paper, gate_fine and "
                                        "gate_fine_rus", "5b48387"),
    "hazard_heading": Retired(False, "docs/navigation-study.md section 12.6, rows gate_*_head*", "18570b5"),
    "gate_scale": Retired(1.0, "docs/navigation-study.md section 12.9, rows gate_ghost_s10_*", "618b968"),
    "gate_branches": Retired(False, "docs/navigation-study.md section 12.9, row gate_ghost_branches_p0", "e082171"),
    "teacher_share": Retired(0.0, "docs/navigation-study.md section 12.16, row teach50", "48cb77b"),
    "r_teacher": Retired(0.0, "docs/navigation-study.md section 12.16, rows of the teacher's reward", "5bff48b"),
}
"""Retired keys of the training configuration (`brl train`, `brl sweep` grids)."""

RETIRED_PARAMS: dict[str, Retired] = {
    "exploration": Retired("tau", "docs/lane-keeping-study.md, rows 37 and 39; docs/navigation-study.md row 16"),
    "posterior_scale": Retired(5.0, "docs/lane-keeping-study.md, rows 37 and 39"),
    "td_error": Retired("component", "docs/lane-keeping-study.md, row 33"),
}
"""Retired agent parameters (`params.*`; `BRLParams`, and the `params_json` of model files)."""


RETIRED_ACTION_SETS: dict[str, Retired] = {
    "fine_stop_slow": Retired(None, "docs/navigation-study.md section 12.27", "4e10806"),
}
"""Retired values of the `actions` key: action sets measured as not helping (`off` unused)."""


def retired_message(key: str, knob: Retired) -> str:
    """The one line for a retired key: what it was, where its figures are, the commit that reruns it."""
    return (f"'{key}' was retired in brl 0.2 (measured as not helping: {knob.study}); to rerun it, use the brl of "
            f"commit {knob.commit} (git checkout {knob.commit})")


def refuse_retired(layer: dict[str, Any], table: dict[str, Retired], prefix: str = "") -> None:
    """A one-line BrlInputError if an input layer (a --set, a --config file, a grid table) names a retired key."""
    for key in layer:
        if key in table:
            raise BrlInputError(f"config key {retired_message(prefix + key, table[key])}")


def drop_retired(saved: dict[str, Any], table: dict[str, Retired], where: str) -> dict[str, Any]:
    """A saved configuration of an older brl without its retired keys; one that used a retired knob (a value other
    than its off value) is refused with one line naming `where` (a file)."""
    out = dict(saved)
    for key, knob in table.items():
        if key in out:
            if out[key] != knob.off:
                raise BrlInputError(f"{where} was made with {key} = {out[key]!r}: {retired_message(key, knob)}")
            del out[key]
    return out


def unknown_action_set(actions: str, known: Iterable[str]) -> str:
    """The one line for an action set this brl does not have: a retired one (its study, the commit that reruns it)
    or an unknown name (the sets there are)."""
    if actions in RETIRED_ACTION_SETS:
        return f"action set {retired_message(actions, RETIRED_ACTION_SETS[actions])}"
    return f"unknown action set '{actions}'; choose one of {', '.join(known)}"
