"""brl: Bayesian RL of vision-based vehicular control on a CPU-only town simulator."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("brl")
except PackageNotFoundError:  # running from a source tree without installation
    __version__ = "0.0.0+unknown"
