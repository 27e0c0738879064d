"""Parameters of the Bayesian RL agent (paper Table 'Parameter Settings' plus documented extras)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

from brlcli.retired import RETIRED_PARAMS, drop_retired

VARIANTS = ("paper", "reference-code")
"""`paper`: the equations as printed. `reference-code`: Q + qhat normalised over actions per component and
m_t = argmax_m p(m | a_t, s_t) inside the TD error, as in the authors' code (docs/method.md)."""

NEW_Q_RULES = ("constant", "nearest")
"""The Q column of a component created after the bad action a_t (Algorithm 1 does not say; docs/method.md):
`constant`: init_q for every action and new_q_taken for a_t (the authors' code); `nearest`: a copy of the l_inf-nearest
component m_t's column, with Q[a_t, new] = the step's TD target r_t + gamma Q[a', m']."""

STEP_SIZES = ("schedule", "visits", "action-visits")
"""The step size of the Q update (eq. 8): `schedule`, the paper's global alpha_t; `visits` (outside the paper),
min(alpha_t, 1 / (kappa_m - D)) for component m, i.e. one over its weighted count of updates plus one, so that a
component's Q is an average of its TD targets rather than the last of them; `action-visits` (outside the paper),
min(alpha_t, 1 / (n[a, m] + 1)) with n[a, m] the weighted count of updates of Q[a, m] itself, so that each action
value is the average of its own TD targets."""

AT_CAPACITY_POLICIES = ("merge", "skip")
"""What learn() does when it would create a component but `max_components` are in use:
`merge` updates the l_inf-nearest component m_t with the usual weight rule instead (Q and NIW update);
`skip` leaves Q and the components unchanged. Both report weight_case "capacity" and never raise."""

_CHOICES = {"variant": VARIANTS, "at_capacity": AT_CAPACITY_POLICIES, "new_q": NEW_Q_RULES, "step_size": STEP_SIZES}
"""The string fields of BRLParams and their allowed values."""


@dataclass(frozen=True)
class BRLParams:
    """Every learning parameter of the agent; `BRLParams()` is the paper's setting."""

    gamma: float = 0.9
    """Discount ('forgetting') factor in the TD error, eq. 5."""
    alpha_init: float = 0.99
    """Initial Q learning rate alpha, eq. 8."""
    alpha_rate: float = 1e-5
    """Per-step schedule rate: alpha <- alpha + alpha_rate (alpha_final - alpha)."""
    alpha_final: float = 0.01
    tau_init: float = 0.5
    """Initial temperature of the behaviour policy, eq. 11 (probability mass moved to the greedy action)."""
    tau_rate: float = 7e-3
    tau_final: float = 0.99
    rho_init: float = 0.1
    """Initial l_inf distance under which the nearest component is always updated (never a new one)."""
    rho_rate: float = 3e-7
    rho_final: float = 0.01
    T_l: float = -10.0
    """Lower TD threshold: below it the action was bad (weight p(m|not a, s); may create a component)."""
    T_u: float = -5.0
    """Upper TD threshold: above it the action was good (weight p(m|a, s))."""
    variant: str = "paper"
    """'paper' or 'reference-code' (see VARIANTS)."""
    max_components: int = 2000
    """Upper bound on mixture components (memory ~ 3 * 8 * D^2 bytes each: 21.6 kB at D = 30)."""
    at_capacity: str = "merge"
    """Behaviour when a creation is requested at max_components (see AT_CAPACITY_POLICIES)."""
    init_scatter: float = 0.1
    """A new component's scatter matrix is init_scatter * I."""
    init_q: float = 0.1
    """A new component's Q column, every action."""
    new_q_taken: float = -1.0
    """Q[a_t, new] of a component created after the bad action a_t."""
    new_q: str = "constant"
    """How a new component's Q column starts (see NEW_Q_RULES)."""
    step_size: str = "schedule"
    """The Q update's step size (see STEP_SIZES); 'schedule' is the paper's."""

    def __post_init__(self) -> None:
        """Validate every field; a bad value raises ValueError naming it."""
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name in _CHOICES:
                if not isinstance(value, str) or value not in _CHOICES[f.name]:
                    raise ValueError(f"BRLParams.{f.name} must be one of {', '.join(_CHOICES[f.name])}, "
                                     f"got {value!r}")
            elif f.name == "max_components":
                if isinstance(value, bool) or not isinstance(value, int):
                    raise ValueError(f"BRLParams.max_components must be an integer, got {value!r}")
            else:
                if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
                    raise ValueError(f"BRLParams.{f.name} must be a finite number, got {value!r}")
                object.__setattr__(self, f.name, float(value))  # ints from JSON or callers become floats
        if self.max_components < 1:
            raise ValueError(f"BRLParams.max_components must be >= 1, got {self.max_components}")
        unit = ("gamma", "alpha_init", "alpha_final", "tau_init", "tau_final",
                "alpha_rate", "tau_rate", "rho_rate")
        for name in unit:
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"BRLParams.{name} must lie in [0, 1], got {value}")
        for name in ("rho_init", "rho_final"):
            if getattr(self, name) < 0.0:
                raise ValueError(f"BRLParams.{name} must be >= 0, got {getattr(self, name)}")
        if self.init_scatter <= 0.0:
            raise ValueError(f"BRLParams.init_scatter must be > 0, got {self.init_scatter}")
        if self.T_l > self.T_u:
            raise ValueError(f"BRLParams.T_l ({self.T_l}) must not exceed T_u ({self.T_u})")

    @classmethod
    def reference_code(cls, **overrides: Any) -> BRLParams:
        """The authors' code: gamma 0.8, rho_rate 3e-5, alpha never decays, variant 'reference-code'."""
        base = cls(gamma=0.8, rho_rate=3e-5, alpha_rate=0.0, variant="reference-code")
        return replace(base, **overrides) if overrides else base

    def to_dict(self) -> dict[str, Any]:
        """Plain dict of every field (JSON-serialisable)."""
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any], where: str = "the parameters") -> BRLParams:
        """Build from a dict; unknown keys raise ValueError, missing keys take their defaults. Retired keys
        (`brlcli.retired.RETIRED_PARAMS`) of an older brl's file at their off values are dropped; `where` names that
        file in the error for one that used a retired knob."""
        if not isinstance(data, dict):
            raise ValueError(f"BRLParams needs a mapping, got {type(data).__name__}")
        data = drop_retired(data, RETIRED_PARAMS, where)
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"unknown BRLParams key(s) (params.*): {', '.join(map(str, unknown))}; known keys: "
                             f"{', '.join(sorted(known))}")
        return cls(**data)
