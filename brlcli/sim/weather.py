"""CARLA 0.8 weather presets: how each one lights and colours the RGB camera image (never the labels)."""

from __future__ import annotations

from dataclasses import dataclass

from brlcli.errors import BrlInputError


@dataclass(frozen=True)
class Weather:
    """Appearance parameters of a weather preset; colours are RGB in 0..1."""

    id: int
    name: str
    sun_elevation_deg: float
    sun_azimuth_deg: float
    sun_colour: tuple[float, float, float]
    sun_strength: float  # directional light share, 0 (overcast) .. 1
    ambient: float  # light on faces turned away from the sun
    sky_zenith: tuple[float, float, float]
    sky_horizon: tuple[float, float, float]
    wetness: float  # 0 dry .. 1 flooded: darker road with sky reflections
    rain: float  # 0 .. 1 rain streak density
    visibility_m: float  # haze: distance at which 63 % of the colour is fog
    fog_colour: tuple[float, float, float]


WEATHERS: dict[int, Weather] = {
    w.id: w
    for w in (
        Weather(1, "ClearNoon", 70, 40, (1.0, 0.98, 0.92), 1.0, 0.55, (0.30, 0.52, 0.90), (0.72, 0.83, 0.95),
                0.0, 0.0, 900.0, (0.78, 0.85, 0.93)),
        Weather(3, "WetNoon", 70, 40, (1.0, 0.98, 0.92), 0.9, 0.55, (0.33, 0.52, 0.85), (0.75, 0.82, 0.90),
                0.55, 0.0, 700.0, (0.75, 0.80, 0.86)),
        Weather(4, "WetCloudyNoon", 65, 60, (0.92, 0.93, 0.95), 0.35, 0.70, (0.55, 0.58, 0.62),
                (0.74, 0.76, 0.78), 0.55, 0.0, 400.0, (0.70, 0.72, 0.74)),
        Weather(6, "HardRainNoon", 60, 40, (0.85, 0.87, 0.90), 0.15, 0.65, (0.38, 0.40, 0.43),
                (0.55, 0.57, 0.60), 1.0, 1.0, 140.0, (0.52, 0.54, 0.57)),
        Weather(8, "ClearSunset", 8, 250, (1.0, 0.70, 0.45), 0.9, 0.62, (0.25, 0.30, 0.55), (0.98, 0.62, 0.38),
                0.0, 0.0, 600.0, (0.90, 0.62, 0.45)),
        Weather(10, "WetSunset", 8, 250, (1.0, 0.70, 0.45), 0.8, 0.60, (0.25, 0.30, 0.52), (0.95, 0.60, 0.40),
                0.6, 0.0, 450.0, (0.85, 0.60, 0.46)),
        Weather(14, "SoftRainSunset", 10, 250, (0.95, 0.70, 0.52), 0.45, 0.62, (0.30, 0.30, 0.42),
                (0.80, 0.58, 0.46), 0.7, 0.45, 250.0, (0.70, 0.55, 0.48)),
    )
}

TRAIN_WEATHERS = (1, 3, 6, 8)
TEST_WEATHERS = (4, 14)


def get_weather(id_or_name: int | str | Weather) -> Weather:
    """Weather preset by CARLA id (1) or name ('ClearNoon', case-insensitive)."""
    if isinstance(id_or_name, Weather):
        return id_or_name
    text = str(id_or_name).strip()
    if text.lstrip("-").isdigit() and int(text) in WEATHERS:
        return WEATHERS[int(text)]
    for w in WEATHERS.values():
        if w.name.lower() == text.lower():
            return w
    choices = ", ".join(f"{w.id} {w.name}" for w in WEATHERS.values())
    raise BrlInputError(f"unknown weather '{id_or_name}'; choose one of: {choices}")
