"""Weather presets: CARLA ids and names resolve; anything else is a one-line input error."""

from __future__ import annotations

import pytest

from brlcli.errors import BrlInputError
from brlcli.sim import TEST_WEATHERS, TRAIN_WEATHERS, WEATHERS, Weather, get_weather

CARLA_WEATHERS = {
    1: "ClearNoon",
    3: "WetNoon",
    4: "WetCloudyNoon",
    6: "HardRainNoon",
    8: "ClearSunset",
    10: "WetSunset",
    14: "SoftRainSunset",
}


def test_the_preset_table_is_carlas():
    assert {k: w.name for k, w in WEATHERS.items()} == CARLA_WEATHERS
    assert set(TRAIN_WEATHERS) == {1, 3, 6, 8}
    assert set(TEST_WEATHERS) == {4, 14}


@pytest.mark.parametrize(("wid", "name"), sorted(CARLA_WEATHERS.items()))
def test_id_and_name_resolve_to_the_same_preset(wid, name):
    by_id = get_weather(wid)
    assert isinstance(by_id, Weather)
    assert (by_id.id, by_id.name) == (wid, name)
    assert get_weather(str(wid)) is by_id
    assert get_weather(name) is by_id
    assert get_weather(name.lower()) is by_id
    assert get_weather(f"  {name.upper()} ") is by_id
    assert get_weather(by_id) is by_id


def test_presets_differ_in_appearance():
    looks = {(w.sky_zenith, w.sun_colour, w.sun_strength, w.wetness, w.rain, w.visibility_m) for w in WEATHERS.values()}
    assert len(looks) == len(WEATHERS)
    assert get_weather("HardRainNoon").rain > 0 and get_weather("ClearNoon").rain == 0


@pytest.mark.parametrize("bad", [0, 2, 5, 15, -1, "Sunny", "", "ClearNoonX", "1.0", None])
def test_unknown_weather_is_an_input_error(bad):
    with pytest.raises(BrlInputError) as info:
        get_weather(bad)
    msg = str(info.value)
    assert "\n" not in msg
    assert "ClearNoon" in msg  # the message lists the choices
