"""The Bayesian RL agent (paper Section III): parameters, the mixture model and its learning step."""

from brlcli.agent.bayes import (
    FORMAT_VERSION,
    BayesianAgent,
    LearnStep,
    chol_rank1_update,
    forward_substitution,
    log_likelihoods,
    niw_update,
    student_t_logpdf,
)
from brlcli.agent.params import AT_CAPACITY_POLICIES, VARIANTS, BRLParams

__all__ = [
    "AT_CAPACITY_POLICIES",
    "FORMAT_VERSION",
    "VARIANTS",
    "BRLParams",
    "BayesianAgent",
    "LearnStep",
    "chol_rank1_update",
    "forward_substitution",
    "log_likelihoods",
    "niw_update",
    "student_t_logpdf",
]
