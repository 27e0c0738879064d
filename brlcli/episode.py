"""One benchmark episode's specification (`EpisodeSpec`), below the suites that list them and the policies that
drive them."""

from __future__ import annotations

import hashlib
from dataclasses import asdict, dataclass


@dataclass(frozen=True)
class EpisodeSpec:
    """One benchmark episode: where it starts and ends, in which town, weather and traffic, with its time limit."""

    suite: str
    condition: str
    task: str
    town: str
    weather: int
    index: int
    start: tuple[float, float, float]
    goal: tuple[float, float, float]
    route_length_m: float
    timeout_s: float
    vehicles: int = 0
    pedestrians: int = 0
    end_on_collision: bool = False
    """NoCrash: a collision above CoRL2017's intensity threshold ends the episode as a failure."""

    @property
    def id(self) -> str:
        """Stable identifier: suite/town/condition/task/weather/index."""
        return f"{self.suite}/{self.town}/{self.condition}/{self.task}/w{self.weather:02d}/{self.index:02d}"

    def seed(self, base: int) -> int:
        """Per-episode seed derived from the identifier (independent of order, workers and shards)."""
        digest = hashlib.sha256(f"{base}:{self.id}".encode()).digest()
        return int.from_bytes(digest[:4], "little")

    def as_dict(self) -> dict:
        """JSON-ready form."""
        return asdict(self)
