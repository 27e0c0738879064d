"""brl's simulator: CARLA-like towns on pybullet with a forward camera, labels, measurements, weather, traffic."""

from brlcli.classes import CarlaClass, colorize_labels
from brlcli.sim.camera import CameraConfig
from brlcli.sim.roadnet import Command, RoadNetwork, Route
from brlcli.sim.town import Town, available_towns, load_town
from brlcli.sim.vehicle import Control
from brlcli.sim.weather import TEST_WEATHERS, TRAIN_WEATHERS, WEATHERS, Weather, get_weather
from brlcli.sim.world import Frame, Measurements, World

__all__ = [
    "TEST_WEATHERS",
    "TRAIN_WEATHERS",
    "WEATHERS",
    "CameraConfig",
    "CarlaClass",
    "Command",
    "Control",
    "Frame",
    "Measurements",
    "RoadNetwork",
    "Route",
    "Town",
    "Weather",
    "World",
    "available_towns",
    "colorize_labels",
    "get_weather",
    "load_town",
]
