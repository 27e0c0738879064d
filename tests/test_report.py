"""`brl report`: metrics on hand-made episodes, merging and refusing results, determinism, the CLI's errors.

Results directories are synthetic (bench.json + results.jsonl + tiny frames files written here): no simulator runs.
"""

from __future__ import annotations

import csv
import gzip
import io
import json
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from brlcli.errors import BrlInputError
from brlcli.report import build_report
from brlcli.report.tables import model_stats

TOWNS = {"town01": "3", "town02": "3"}
TABLE_FORMATS = "csv,tex"


# --------------------------------------------------------------------------------------------------------------
# Synthetic results


def _npz_bytes(arrays: dict[str, np.ndarray]) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def paper_episode(policy: str, setting: str, n: int, steps: int = 20, off: int = 0, other: int = 0, both: int = 0,
                  success: bool = True, collided: bool = False, km: float = 0.1) -> dict:
    """A paper-suite episode record: `off` steps only off road, `other` only in the other lane, `both` in both."""
    town = ("town01", "town02")[n % 2]
    condition = {"town01": "training_town", "town02": "unseen_town"}[town]
    task = ("straight", "right_curve", "left_curve")[n % 3]
    weather = (1, 4, 14)[(n // 3) % 3]
    ep_id = f"paper/{town}/{condition}/{task}/w{weather:02d}/{n:02d}"
    return {"suite": "paper", "condition": condition, "task": task, "town": town, "weather": weather, "index": n,
            "id": ep_id, "policy": policy, "setting": setting, "seed": 1000 + n, "success": success,
            "time_s": steps / 10, "timeout_s": 40.0, "route_length_m": 90.0, "km": km,
            "infractions": {"offroad": 0, "otherlane": 0, "collision_other": 0, "collision_vehicles": 0,
                            "collision_pedestrians": 0},
            "collided": collided, "steps": steps, "offroad_steps": off + both, "otherlane_steps": other + both,
            "either_steps": off + other + both, "final_distance_m": 1.0 if success else 30.0,
            "frames_file": f"frames/{policy.replace('/', '_')}/{ep_id.replace('/', '_')}.npz"}


def frames_of(ep: dict) -> dict[str, np.ndarray]:
    """Per-frame arrays (steps + 1 frames) consistent with the episode's step counts."""
    n = ep["steps"] + 1
    off_only = ep["offroad_steps"] - (ep["offroad_steps"] + ep["otherlane_steps"] - ep["either_steps"])
    both = ep["offroad_steps"] - off_only
    other_only = ep["otherlane_steps"] - both
    offroad, otherlane = np.zeros(n), np.zeros(n)
    offroad[1:1 + off_only] = 0.5
    otherlane[1 + off_only:1 + off_only + other_only] = 0.6
    offroad[1 + off_only + other_only:1 + off_only + other_only + both] = 0.3
    otherlane[1 + off_only + other_only:1 + off_only + other_only + both] = 0.3
    otherlane[-1] = 0.1  # below the 20 % threshold: in the histogram, not in the counts
    x = np.linspace(0.0, ep["km"] * 1000.0, n)
    return {"intersection_offroad": offroad, "intersection_otherlane": otherlane, "x": x, "y": np.zeros(n)}


def write_results(path: Path, episodes: list[dict], suite: str = "paper", suite_version: int = 1,
                  towns: dict[str, str] | None = None, shard: tuple[int, int] = (1, 1)) -> Path:
    """A results directory as `brl bench` writes it."""
    path.mkdir(parents=True, exist_ok=True)
    policies = sorted({e["policy"] for e in episodes})
    config = {"suite": suite, "suite_version": suite_version, "town_versions": towns or dict(TOWNS),
              "policies": [{"kind": "brl", "name": p, "model": f"runs/{p}/model.npz", "deploy": "gt",
                            "segnet": None} for p in policies],
              "deploy": "gt", "seed": 0, "selection": {}, "shard": list(shard)}
    (path / "bench.json").write_text(json.dumps({"brl_version": "0.1.0", "git_commit": "test", "python": "3.11",
                                                 "config": config}))
    with open(path / "results.jsonl", "w") as fh:
        for ep in episodes:
            fh.write(json.dumps(ep, sort_keys=True) + "\n")
            frames = path / ep["frames_file"]
            frames.parent.mkdir(parents=True, exist_ok=True)
            frames.write_bytes(_npz_bytes(frames_of(ep)))
    return path


def model_set(setting: str, models: int = 2, episodes: int = 6) -> list[dict]:
    """Episodes of a small model set with varied outcomes."""
    out = []
    for m in range(models):
        for n in range(episodes):
            out.append(paper_episode(f"set_{setting.lower()}/seed_{m}", setting, n, steps=20 + n, off=(n + m) % 3,
                                     other=(2 * n + m) % 4, both=n % 2, success=(n + m) % 3 != 0,
                                     collided=(n * (m + 1)) % 5 == 0, km=0.08 + 0.01 * n))
    return out


def read_csv(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def table_bytes(out: Path) -> dict[str, bytes]:
    """Every md, tex and csv file of a report."""
    return {str(p.relative_to(out)): p.read_bytes() for p in sorted(out.rglob("*"))
            if p.suffix in (".md", ".tex", ".csv")}


# --------------------------------------------------------------------------------------------------------------
# Metrics on hand-made episodes


def _report_of(tmp_path: Path, suite: str, episodes: list[dict]) -> Path:
    """A csv + md report of hand-made results records of one suite; returns its directory."""
    path = tmp_path / suite
    path.mkdir()
    (path / "bench.json").write_text(json.dumps({"config": {"suite": suite, "suite_version": 1,
                                                            "town_versions": TOWNS}}))
    (path / "results.jsonl").write_text("".join(json.dumps(e) + "\n" for e in episodes))
    out = tmp_path / "rep"
    build_report([path], out=out, formats="csv,md")
    return out


def test_score_and_either_on_hand_made_episodes(tmp_path: Path) -> None:
    eps = [
        paper_episode("m/a", "TGDG", 0, steps=10, off=2, success=True, collided=False, km=0.1),
        paper_episode("m/a", "TGDG", 1, steps=10, other=3, success=False, collided=False, km=0.2),
        # 20 steps: 2 only off road, 2 only in the other lane, 2 in both: Either counts those 2 once
        paper_episode("m/a", "TGDG", 2, steps=20, off=2, other=2, both=2, success=True, collided=True, km=0.3),
    ]
    m = model_stats("TGDG", "m/a", eps)
    # steps 40: off-road 2 + 4 = 6, other lane 3 + 4 = 7, either 2 + 3 + 6 = 11 (not 6 + 7)
    assert (m.steps, m.offroad, m.otherlane, m.either) == (40, 6 / 40, 7 / 40, 11 / 40)
    assert m.success == pytest.approx(2 / 3) and m.no_collision == pytest.approx(2 / 3)
    assert m.score == pytest.approx(((1 - 11 / 40) + 2 / 3 + 2 / 3) / 3)
    assert m.dist_m == pytest.approx(600.0)

    out = tmp_path / "rep"
    build_report([write_results(tmp_path / "r", eps)], out=out, formats=TABLE_FORMATS)
    row = read_csv(out / "tables" / "paper_models.csv")[0]
    assert row["Either [%]"] == "27.5000" and row["Offroad [%]"] == "15.0000" and row["Otherlane [%]"] == "17.5000"
    assert float(row["Score"]) == pytest.approx(((1 - 0.275) + 2 / 3 + 2 / 3) / 3, abs=1e-6)
    assert row["Dist [m]"] == "600.000" and row["Best"] == "best"


def test_paper_checks_and_average_best_rows(tmp_path: Path) -> None:
    # the two checks in docs/benchmarks.md, 'Metrics', through the table: Either 2.4 %, 100 %, 100 % -> 0.99
    good = [paper_episode("m/good", "TGDG", n, steps=1000, off=24 if n == 0 else 0) for n in range(1)]
    # Either 52.4 %, 41.7 %, 50 % -> 0.46 (12 episodes: 5 successes, 6 collisions; 524 of 1000 steps)
    bad = [paper_episode("m/bad", "TGDG", n, steps=1000 if n == 0 else 0, off=524 if n == 0 else 0,
                         success=n < 5, collided=n % 2 == 0) for n in range(12)]
    out = tmp_path / "rep"
    build_report([write_results(tmp_path / "r", good + bad)], out=out, formats=TABLE_FORMATS)
    rows = {r["Policy"]: r for r in read_csv(out / "tables" / "paper_models.csv")}
    assert round(float(rows["m/good"]["Score"]), 2) == 0.99 and rows["m/good"]["Best"] == "best"
    assert round(float(rows["m/bad"]["Score"]), 2) == 0.46
    table = read_csv(out / "tables" / "paper_test_table.csv")
    avg = next(r for r in table if r["Setting"] == "TGDG" and r["Row"] == "average" and r["Source"] == "ours")
    scores = np.array([float(rows["m/good"]["Score"]), float(rows["m/bad"]["Score"])])
    assert float(avg["Score"]) == pytest.approx(scores.mean(), abs=1e-6)
    assert float(avg["Score std"]) == pytest.approx(scores.std(), abs=1e-6)
    best = next(r for r in table if r["Row"].startswith("best model: "))
    assert best["Row"] == "best model: m/good"
    published = [r for r in table if r["Source"] == "published"]
    assert len(published) == 10  # every row of the paper's Table II (tab:ZGHSmall), RL and IL included
    assert {"RL", "IL"} <= {r["Setting"] for r in published}


def test_beta_posteriors_match_scipy(tmp_path: Path) -> None:
    eps = model_set("TGDG", models=3, episodes=7)
    out = tmp_path / "rep"
    build_report([write_results(tmp_path / "r", eps)], out=out, formats=TABLE_FORMATS)
    rows = read_csv(out / "tables" / "paper_posteriors.csv")
    pooled = [r for r in rows if r["Scope"].startswith("pooled")]
    assert {r["Rate"] for r in pooled} == {"success", "collision-free"}
    n_ok = sum(e["success"] for e in eps)
    assert next(r for r in pooled if r["Rate"] == "success")["Successes"] == str(n_ok)
    assert {r["Scope"] for r in rows if r["Setting"] == "TEDE"} == {"missing: no results for this setting"}
    for r in (r for r in rows if r["Successes"]):
        s, f = int(r["Successes"]), int(r["Failures"])
        ref = stats.beta(s + 0.5, f + 0.5)
        assert float(r["Mean"]) == pytest.approx(ref.mean(), abs=1e-6)
        assert float(r["95 % lo"]) == pytest.approx(ref.ppf(0.025), abs=1e-6)
        assert float(r["95 % hi"]) == pytest.approx(ref.ppf(0.975), abs=1e-6)


def test_corl_success_over_weathers_and_km_between_infractions(tmp_path: Path) -> None:
    def ep(n: int, weather: int, success: bool, offroad: int, condition: str = "training") -> dict:
        town = "town01" if condition in ("training", "new_weather") else "town02"
        return {"suite": "corl2017", "condition": condition, "task": "straight", "town": town, "weather": weather,
                "index": n, "id": f"corl2017/{town}/{condition}/straight/w{weather:02d}/{n:02d}", "policy": "seed_3",
                "setting": "TGDG", "seed": n, "success": success, "km": 0.5, "steps": 100, "collided": False,
                "either_steps": 10, "infractions": {"offroad": offroad, "otherlane": 0, "collision_other": 0,
                                                    "collision_vehicles": 0, "collision_pedestrians": 0}}

    eps = [ep(0, 1, True, 1), ep(1, 1, False, 0), ep(2, 3, True, 0), ep(3, 4, False, 2, "new_town")]
    out = _report_of(tmp_path, "corl2017", eps)
    success = read_csv(out / "tables" / "corl_success.csv")
    ours = next(r for r in success if r["Task"] == "Straight" and r["Source"] == "ours")
    assert float(ours["Training"]) == pytest.approx(75.0)  # weather 1: 1/2, weather 3: 1/1 -> mean 0.75, not 2/3
    assert float(ours["New town"]) == 0.0 and ours["New weather"] == ""
    carla = next(r for r in success if r["Task"] == "Straight" and r["Agent"] == "MP")
    assert (carla["Source"], carla["Training"]) == ("published", "98")
    km = read_csv(out / "tables" / "corl_km_between_infractions.csv")
    ours_km = {r["Infraction"]: r for r in km if r["Source"] == "ours"}
    assert float(ours_km["Sidewalk (off-road)"]["Training"]) == pytest.approx(1.5)  # 1.5 km / 1 event
    assert ours_km["Opposite lane"]["Training"] == ">1.500000"
    assert float(ours_km["Sidewalk (off-road)"]["New town"]) == pytest.approx(0.25)
    paper = next(r for r in km if r["Infraction"] == "Opposite lane" and r["Agent"] == "TGDE")
    assert (paper["Source"], paper["New town"], paper["Training"]) == ("published", "4.10", "")
    md = (out / "report.md").read_text()
    assert "| Opposite lane | seed_3 (TGDG) | ours | > 1.50 |" in md
    assert "75.0 (n=3)" in md


def test_nocrash_success_posteriors_and_outcomes(tmp_path: Path) -> None:
    def ep(n: int, task: str, success: bool, crashed: bool, condition: str = "training") -> dict:
        town = "town01" if condition in ("training", "new_weather") else "town02"
        return {"suite": "nocrash", "condition": condition, "task": task, "town": town, "weather": 1, "index": n,
                "id": f"nocrash/{town}/{condition}/{task}/w01/{n:02d}", "policy": "autopilot",
                "setting": "autopilot", "seed": n, "success": success, "km": 0.4, "steps": 100,
                "collided": crashed, "crashed": crashed}

    eps = [ep(0, "empty", True, False), ep(1, "empty", True, False), ep(2, "dense", False, True),
           ep(3, "dense", True, False), ep(4, "dense", False, False), ep(5, "regular", True, False, "new_town")]
    out = _report_of(tmp_path, "nocrash", eps)
    rows = {r["Traffic"]: r for r in read_csv(out / "tables" / "nocrash_success.csv")}
    assert float(rows["Dense"]["Training"]) == pytest.approx(100.0 / 3, abs=1e-3)
    assert float(rows["Empty"]["Training"]) == 100.0 and rows["Empty"]["New town"] == ""
    assert float(rows["Regular"]["New town"]) == 100.0
    lo, hi = stats.beta(1.5, 2.5).ppf([0.025, 0.975])  # 1 success, 2 failures, Jeffreys prior
    assert f"33.3 [{100 * lo:.1f}, {100 * hi:.1f}] (n=3)" in (out / "report.md").read_text()
    outcomes = {r["Traffic"]: r for r in read_csv(out / "tables" / "nocrash_outcomes.csv")}
    dense = outcomes["Dense"]
    assert [float(dense[k]) for k in ("Success [%]", "Collision [%]", "Timeout [%]")] == \
        pytest.approx([100 / 3, 100 / 3, 100 / 3], abs=1e-3)
    assert "NoCrash benchmark" in (out / "report.md").read_text()


def test_nocrash_agents_on_different_episode_sets_are_compared_on_the_common_ones(tmp_path: Path) -> None:
    def ep(policy: str, n: int, success: bool, crashed: bool = False) -> dict:
        return {"suite": "nocrash", "condition": "training", "task": "dense", "town": "town01", "weather": 1,
                "index": n, "id": f"nocrash/town01/training/dense/w01/{n:02d}", "policy": policy,
                "setting": policy, "seed": n, "success": success, "km": 0.4, "steps": 100, "collided": crashed,
                "crashed": crashed}

    full = [ep("full", n, n % 2 == 0, crashed=n % 2 == 1) for n in range(10)]  # the whole suite: 5 of 10
    subset = [ep("subset", n, True) for n in (0, 1, 2)]  # a fixed subset: its ids are among the full run's
    out = _report_of(tmp_path, "nocrash", full + subset)
    whole = {r["Agent"]: r for r in read_csv(out / "tables" / "nocrash_success.csv") if r["Traffic"] == "Dense"}
    assert float(whole["full (full)"]["Training"]) == 50.0
    common = {r["Agent"]: r for r in read_csv(out / "tables" / "nocrash_success_common.csv")
              if r["Traffic"] == "Dense"}
    assert float(common["full (full)"]["Training"]) == pytest.approx(200 / 3, abs=1e-3)  # episodes 0, 1, 2 only
    assert float(common["subset (subset)"]["Training"]) == 100.0
    ends = {r["Agent"]: r for r in read_csv(out / "tables" / "nocrash_outcomes_common.csv")}
    assert ends["full (full)"]["Episodes"] == "3" and float(ends["full (full)"]["Collision [%]"]) == \
        pytest.approx(100 / 3, abs=1e-3)
    assert "on the 3 episodes every agent drove" in (out / "report.md").read_text()
    (tmp_path / "same").mkdir()
    same = _report_of(tmp_path / "same", "nocrash", full + [ep("other", n, False) for n in range(10)])
    assert not (same / "tables" / "nocrash_success_common.csv").exists()  # one episode set: no extra tables


def test_a_model_set_gets_a_mean_row_with_std_worst_and_best(tmp_path: Path) -> None:
    def ep(policy: str, n: int, success: bool, suite: str = "corl2017", task: str = "one_curve") -> dict:
        return {"suite": suite, "condition": "training", "task": task, "town": "town01", "weather": 1, "index": n,
                "id": f"{suite}/town01/training/{task}/w01/{n:02d}", "policy": policy, "setting": "TGDG",
                "seed": n, "success": success, "km": 0.5, "steps": 100, "collided": False, "crashed": False,
                "either_steps": 0, "infractions": {"offroad": 0, "otherlane": 0, "collision_other": 0,
                                                   "collision_vehicles": 0, "collision_pedestrians": 0}}

    wins = {"nav/seed_0": [True, True, True, True], "nav/seed_1": [True, True, False, False],
            "nav/seed_2": [True, False, False, False], "solo": [False, False, False, False]}
    eps = [ep(p, n, w) for p, ws in wins.items() for n, w in enumerate(ws)]
    out = _report_of(tmp_path, "corl2017", eps)
    rows = {r["Agent"]: r for r in read_csv(out / "tables" / "corl_success.csv")
            if r["Task"] == "One turn" and r["Source"] == "ours"}
    label = "nav: mean of 3 models (TGDG)"
    assert set(rows) == {"nav/seed_0 (TGDG)", "nav/seed_1 (TGDG)", "nav/seed_2 (TGDG)", "solo (TGDG)", label}
    assert float(rows[label]["Training"]) == pytest.approx(100 * (1 + 0.5 + 0.25) / 3, abs=1e-3)
    std = 100 * np.std([1, 0.5, 0.25], ddof=1)
    assert f"| {label} | ours | 58.3 ± {std:.1f} [25.0, 100.0] |" in (out / "report.md").read_text()
    (tmp_path / "nc").mkdir()
    nocrash = _report_of(tmp_path / "nc", "nocrash", [{**e, "suite": "nocrash", "task": "empty"} for e in eps])
    nc_rows = {r["Agent"]: r for r in read_csv(nocrash / "tables" / "nocrash_success.csv") if r["Traffic"] == "Empty"}
    assert float(nc_rows[label]["Training"]) == pytest.approx(100 * 1.75 / 3, abs=1e-3)
    assert [a for a in nc_rows if "mean of" in a] == [label]  # one set row, none for the lone policy


def test_a_long_setting_label_is_a_key_in_the_tables_and_whole_in_a_note_and_the_csv(tmp_path: Path) -> None:
    long = "TGDG (action-averaging-committee, navigation, fine steering, stop primitive, imitation)"
    eps = [{"suite": "nocrash", "condition": "training", "task": "dense", "town": "town01", "weather": 1,
            "index": n, "id": f"nocrash/town01/training/dense/w01/{n:02d}", "policy": policy, "setting": setting,
            "seed": n, "success": n % 2 == 0, "km": 0.5, "steps": 100, "collided": False, "crashed": n % 2 == 1,
            "either_steps": 0, "infractions": {"offroad": 0, "otherlane": 0, "collision_other": 0,
                                               "collision_vehicles": 0, "collision_pedestrians": 0}}
           for policy, setting in (("nav/seed_0", long), ("nav/seed_1", long), ("mp", "MP-DG"))
           for n in range(4)]
    out = _report_of(tmp_path, "nocrash", eps)
    md = (out / "report.md").read_text()
    assert "| Dense | nav/seed_0 (TGDG [a]) |" in md and "| Dense | nav: mean of 2 models (TGDG [a]) |" in md
    assert "| Dense | mp (MP-DG) |" in md  # a short label stays whole
    assert f"- Settings: [a] {long}." in md and f"nav/seed_0 ({long})" not in md
    agents = {r["Agent"] for r in read_csv(out / "tables" / "nocrash_success.csv")}
    assert agents == {f"nav/seed_0 ({long})", f"nav/seed_1 ({long})", f"nav: mean of 2 models ({long})",
                      "mp (MP-DG)"}


# --------------------------------------------------------------------------------------------------------------
# Merging, missing settings, determinism


def test_merged_shards_equal_the_unsharded_report(tmp_path: Path) -> None:
    eps = model_set("TGDG") + model_set("TEDE", models=3, episodes=4)
    whole = write_results(tmp_path / "whole", eps)
    shard_a = write_results(tmp_path / "shard_a", eps[1::2], shard=(1, 2))
    shard_b = write_results(tmp_path / "shard_b", eps[0::2], shard=(2, 2))
    build_report([whole], out=tmp_path / "rep_whole", formats="md,tex,csv")
    build_report([shard_b, shard_a], out=tmp_path / "rep_shards", formats="md,tex,csv")
    # a shard given twice, and the whole set plus a shard: duplicates merge away
    build_report([shard_a, whole, shard_a], out=tmp_path / "rep_dupes", formats="md,tex,csv")
    ref = table_bytes(tmp_path / "rep_whole")
    assert len(ref) == 1 + 2 * 3 and "report.md" in ref
    assert table_bytes(tmp_path / "rep_shards") == ref
    tables_only = {k: v for k, v in ref.items() if k.startswith("tables/")}
    assert {k: v for k, v in table_bytes(tmp_path / "rep_dupes").items() if k.startswith("tables/")} == tables_only
    dupes = json.loads((tmp_path / "rep_dupes" / "report.json").read_text())
    assert dupes["duplicates_merged"] == len(eps) // 2 and dupes["episodes"] == len(eps)


def test_missing_setting_is_reported(tmp_path: Path) -> None:
    out = tmp_path / "rep"
    build_report([write_results(tmp_path / "r", model_set("TGDG") + model_set("TEDG"))], out=out,
                 formats="md,csv")
    table = read_csv(out / "tables" / "paper_test_table.csv")
    for setting in ("TGDE", "TEDE"):
        ours = [r for r in table if r["Setting"] == setting and r["Source"] == "ours"]
        assert [r["Row"] for r in ours] == ["missing: no results for this setting"]
        assert len([r for r in table if r["Setting"] == setting and r["Source"] == "published"]) == 2
    md = (out / "report.md").read_text()
    assert "Setting TGDE is missing" in md and "Setting TEDE is missing" in md
    assert "Setting TGDG is missing" not in md and "Setting TEDG is missing" not in md
    assert "Missing settings (no results): TGDE, TEDE." in md


def _variant(episodes: list[dict], variant: str) -> list[dict]:
    """The episodes as another method variant's: setting 'TGDG (NAME)', policies and frames files of their own."""
    return [{**e, "policy": f"{variant}/{e['policy']}", "setting": f"{e['setting']} ({variant})",
             "frames_file": e["frames_file"].replace("frames/", f"frames/{variant}_")} for e in episodes]


def test_a_setting_present_only_under_a_variant_label_is_not_missing(tmp_path: Path) -> None:
    """Issue 36: 'Setting TGDG is missing' stood beside 'TGDG (action-averaging-restart)' rows."""
    eps = _variant(model_set("TGDG") + model_set("TEDG"), "action-averaging-restart")
    out = tmp_path / "rep"
    build_report([write_results(tmp_path / "r", eps)], out=out, formats="md,csv")
    md = (out / "report.md").read_text()
    for setting in ("TGDG", "TEDG"):
        assert f"Setting {setting} is missing" not in md
    assert "Setting TGDE is missing" in md and "Setting TEDE is missing" in md
    assert "Missing settings (no results): TGDE, TEDE." in md
    table = read_csv(out / "tables" / "paper_test_table.csv")
    ours = [(r["Setting"], r["Row"].split(":")[0]) for r in table if r["Source"] == "ours"]
    assert ("TGDG (action-averaging-restart)", "average") in ours and ("TGDG", "missing") not in ours
    assert [r for r in ours if r[0] == "TGDE"] == [("TGDE", "missing")]
    posteriors = read_csv(out / "tables" / "paper_posteriors.csv")
    assert {r["Setting"] for r in posteriors if r["Scope"].startswith("missing")} == {"TGDE", "TEDE"}


def test_beta_titles_and_captions_name_baselines_only_when_there_are_some(tmp_path: Path) -> None:
    from brlcli.report.plots import beta_label, beta_panel_titles
    from brlcli.report.tables import Posterior

    sets = [Posterior("TGDG", "best", "best model: gt/seed_2", "success", 66, 0, 1),
            Posterior("TGDG", "pooled", "pooled over 9 models", "success", 408, 186, 9)]
    base = Posterior("autopilot", "policy", "autopilot", "success", 66, 0, 1)
    assert beta_panel_titles(sets, "success")[0] == "Best model per setting"
    assert beta_panel_titles([*sets, base], "success")[0] == "Best model per setting (and baselines)"
    assert beta_panel_titles([*sets, base], "collision-free")[0] == "Best model per setting"  # another rate's
    assert beta_label(sets[0]) == "TGDG gt/seed_2: 66/66, mean 0.99"
    assert beta_label(sets[1]) == "TGDG, 9 models: 408/594, mean 0.69"
    long = Posterior("TGDE (action-averaging-committee)", "best", "best model: brl_gt_committee/seed_6", "success",
                     66, 0, 1)
    assert all(len(line) <= 62 for line in beta_label(long).splitlines())  # wrapped to fit below its panel

    plain = tmp_path / "plain"
    build_report([write_results(tmp_path / "r", model_set("TGDG"))], out=plain, formats="md")
    md = (plain / "report.md").read_text()
    assert "pooled over the setting's model set (right)." in md and "baselines dashed" not in md
    with_base = tmp_path / "with_base"
    eps = model_set("TGDG") + [paper_episode("autopilot", "autopilot", n) for n in range(3)]
    build_report([write_results(tmp_path / "r2", eps)], out=with_base, formats="md")
    assert "(right); baselines dashed." in (with_base / "report.md").read_text()


def test_a_subset_of_the_suite_says_its_distances_are_not_the_published_ones(tmp_path: Path) -> None:
    """Issue 36: the published ~11,000 m stood beside a 10 % subset's metres without a word."""
    out = tmp_path / "subset"
    build_report([write_results(tmp_path / "r", model_set("TGDG"))], out=out, formats="md,csv")
    md = (out / "report.md").read_text()
    assert "A subset: 6 of the suite's 66 episodes per model" in md  # the section's text
    assert ("Dist is not comparable with the published rows in absolute terms: those are for the paper's full test "
            "suite, ours for 6 of the suite's 66 episodes per model (a subset of it)") in md
    assert "### Lane-keeping test table (the paper's Table II)" in md
    assert "tab:" not in md  # the paper's LaTeX labels are no reader's table names

    full = tmp_path / "full"  # 66 episodes per model: the paper suite's size, no note
    build_report([write_results(tmp_path / "f", model_set("TGDG", models=2, episodes=66))], out=full,
                 formats="md")
    md_full = (full / "report.md").read_text()
    assert "not comparable with the published rows" not in md_full and "A subset:" not in md_full

    def corl(n: int) -> dict:
        return {"suite": "corl2017", "condition": "new_town", "task": "straight", "town": "town02", "weather": 1,
                "index": n, "id": f"corl2017/town02/new_town/straight/w01/{n:02d}", "policy": "seed_3",
                "setting": "TGDG", "seed": n, "success": True, "km": 0.3, "steps": 100, "collided": False,
                "either_steps": 0, "infractions": {"offroad": 1, "otherlane": 0, "collision_other": 0,
                                                   "collision_vehicles": 0, "collision_pedestrians": 0}}

    (tmp_path / "c").mkdir()
    corl_md = (_report_of(tmp_path / "c", "corl2017", [corl(n) for n in range(5)]) / "report.md").read_text()
    assert "A subset: 5 of the suite's 1200 episodes per agent." in corl_md
    assert ("The published figures are for the full CoRL2017 suite (25 routes x every weather of a condition); ours "
            "are for 5 of the suite's 1200 episodes per agent (a subset of it), so the km driven are not comparable "
            "in absolute terms. The km between infractions (per-km rates) are") in corl_md
    assert "Gharaee et al. 2020, Table III" in corl_md and "tab:" not in corl_md


def test_baselines_are_extra_rows(tmp_path: Path) -> None:
    eps = model_set("TGDG") + [paper_episode("carla_il", "IL-baseline", n, off=1) for n in range(3)]
    out = tmp_path / "rep"
    build_report([write_results(tmp_path / "r", eps)], out=out, formats="csv")
    rows = read_csv(out / "tables" / "paper_test_table.csv")
    base = [r for r in rows if r["Setting"] == "IL-baseline"]
    assert [(r["Row"], r["Source"], r["Episodes"]) for r in base] == [("carla_il", "ours", "3")]


def test_deterministic_rerun_and_outputs(tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    for seed, success in ((0, 1.0), (1, 0.5)):
        d = runs / f"seed_{seed}"
        d.mkdir(parents=True)
        rng = np.random.default_rng(seed)
        lines = ["step,episode,reward,td_error"] + [f"{i},{i // 50},{-40 + i / 20 + rng.normal():.6f},"
                                                    f"{-100 + rng.normal():.6f}" for i in range(1, 401)]
        (d / "log.csv").write_text("\n".join(lines) + "\n")
        (d / "config.json").write_text(json.dumps({"config": {"input": "gt", "seed": seed}}))
        (d / "summary.json").write_text(json.dumps({"summary": {"eval": {
            "success_rate": success, "either_share": 0.2, "collision_free_rate": 1.0}}}))
    res = write_results(tmp_path / "r", model_set("TGDG") + model_set("TGDE"))
    first = build_report([res], [runs], out=tmp_path / "a")
    second = build_report([res], [runs], out=tmp_path / "b")
    assert first["files"] == second["files"]
    assert table_bytes(tmp_path / "a") == table_bytes(tmp_path / "b")
    for name in ("beta_success", "beta_collision_free", "lane_histogram", "convergence"):
        png = (tmp_path / "a" / "figures" / f"{name}.png").read_bytes()
        assert png[:8] == b"\x89PNG\r\n\x1a\n"
        width, height = struct.unpack(">II", png[16:24])
        assert width == 1000 and height > 300  # fixed 10-inch width at 100 dpi
    md = (tmp_path / "a" / "report.md").read_text()
    assert "![Per-step lane position](figures/lane_histogram.png)" in md
    html = (tmp_path / "a" / "report.html").read_text()
    assert html.count("data:image/png;base64,") == 4 and "<table>" in html
    training = read_csv(tmp_path / "a" / "tables" / "training_runs.csv")
    assert [(r["Run"], r["Mark"]) for r in training] == [("runs/seed_0", "best"), ("runs/seed_1", "worst")]
    prov = json.loads((tmp_path / "a" / "report.json").read_text())
    assert {"brl_version", "git_commit", "config", "inputs", "files"} <= set(prov)
    assert prov["inputs"][0]["suite"] == "paper" and prov["config"]["runs"] == [str(runs)]
    assert not list((tmp_path / "a").rglob("*.tmp"))
    assert tb_has_booktabs(tmp_path / "a" / "tables" / "paper_test_table.tex")


def test_an_archived_results_directory_reports_as_the_original(tmp_path: Path) -> None:
    res = write_results(tmp_path / "r", model_set("TGDG"))
    script = Path(__file__).resolve().parents[1] / "scripts" / "archive_bench.py"
    for dest in ("a1", "a2"):
        subprocess.run([sys.executable, str(script), str(tmp_path / dest), str(res)], check=True, capture_output=True)
    archived = tmp_path / "a1" / "r"
    assert sorted(p.name for p in archived.iterdir()) == ["bench.json", "results.jsonl.gz"]
    assert (archived / "results.jsonl.gz").read_bytes() == (tmp_path / "a2" / "r" / "results.jsonl.gz").read_bytes()
    build_report([res], out=tmp_path / "orig", formats="csv,md")
    rep = build_report([archived], out=tmp_path / "arch", formats="csv,md")
    assert rep["episodes"] == 12
    orig, arch = table_bytes(tmp_path / "orig"), table_bytes(tmp_path / "arch")
    assert orig.keys() == arch.keys() and all(orig[k] == arch[k] for k in orig if k.startswith("tables"))
    (archived / "results.jsonl.gz").write_bytes(b"not gzip")
    with pytest.raises(BrlInputError, match="not readable"):
        build_report([archived], out=tmp_path / "bad", formats="csv")


def test_an_archive_can_rename_a_policy_into_its_model_set(tmp_path: Path) -> None:
    eps = model_set("TGDG", models=2, episodes=3)
    names = sorted({e["policy"] for e in eps})
    res = write_results(tmp_path / "r", eps)
    script = Path(__file__).resolve().parents[1] / "scripts" / "archive_bench.py"

    def run(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, str(script), *args], capture_output=True, text=True)

    assert run("--rename", f"{names[0]}=set/one", str(tmp_path / "a"), str(res)).returncode == 0
    archived = tmp_path / "a" / "r"
    rows = [json.loads(line) for line in gzip.decompress((archived / "results.jsonl.gz").read_bytes()).splitlines()]
    assert {r["policy"] for r in rows} == {"set/one", names[1]}
    renamed = [r for r in rows if r["policy"] == "set/one"]
    assert len(renamed) == 3 and all(r["frames_file"].startswith("frames/set_one/") for r in renamed)
    originals = [json.loads(line) for line in (res / "results.jsonl").read_text().splitlines()]
    assert [{k: v for k, v in r.items() if k not in ("policy", "frames_file")} for r in rows] == \
        [{k: v for k, v in r.items() if k not in ("policy", "frames_file")} for r in originals]
    policies = json.loads((archived / "bench.json").read_text())["config"]["policies"]
    assert [p["name"] for p in policies] == ["set/one", names[1]]
    bad = run("--rename", "nobody=set/x", str(tmp_path / "b"), str(res))
    assert bad.returncode == 2 and not (tmp_path / "b").exists()
    assert bad.stderr.startswith("archive_bench: error: no policy named 'nobody'") and "Traceback" not in bad.stderr
    assert run("--rename", "no-equals-sign", str(tmp_path / "c"), str(res)).returncode == 2
    two = run(str(tmp_path / "d"), str(res), str(tmp_path / "missing"))  # one bad source: nothing archived
    assert two.returncode == 2 and "missing is not a brl bench results directory" in two.stderr
    assert not (tmp_path / "d").exists()


def tb_has_booktabs(path: Path) -> bool:
    text = path.read_text()
    return all(rule in text for rule in ("\\toprule", "\\midrule", "\\bottomrule")) and "\\%" in text


def test_torn_last_line_is_ignored(tmp_path: Path) -> None:
    res = write_results(tmp_path / "r", model_set("TGDG"))
    with open(res / "results.jsonl", "a") as fh:
        fh.write('{"suite": "paper", "condi')
    rep = build_report([res], out=tmp_path / "rep", formats="csv")
    assert rep["episodes"] == 12 and any("torn" in n for n in rep["notes"])


# --------------------------------------------------------------------------------------------------------------
# Refusals: one line, nothing written


def _bad_inputs(tmp_path: Path, case: str) -> list[Path]:
    eps = model_set("TGDG")
    if case == "mixed suite versions":
        return [write_results(tmp_path / "v1", eps[:6]), write_results(tmp_path / "v2", eps[6:], suite_version=2)]
    if case == "mixed town versions":
        return [write_results(tmp_path / "t3", eps[:6]),
                write_results(tmp_path / "t4", eps[6:], towns={"town01": "4", "town02": "3"})]
    if case == "no results":
        return []
    res = write_results(tmp_path / "r", eps)
    lines = (res / "results.jsonl").read_text().splitlines()
    if case == "empty results file":
        (res / "results.jsonl").write_text("")
    elif case == "corrupt results file":
        lines[3] = lines[3][:40]
        (res / "results.jsonl").write_text("\n".join(lines) + "\n")
    elif case == "no bench.json":
        (res / "bench.json").unlink()
    elif case == "no results.jsonl":
        (res / "results.jsonl").unlink()
    elif case == "conflicting duplicates":
        other = json.loads(lines[0])
        other["success"] = not other["success"]
        return [res, write_results(tmp_path / "r2", [other])]
    return [res]


BAD_CASES = ("mixed suite versions", "mixed town versions", "no results", "empty results file",
             "corrupt results file", "no bench.json", "no results.jsonl", "conflicting duplicates")


@pytest.mark.parametrize("case", BAD_CASES)
def test_bad_inputs_are_one_line_errors(tmp_path: Path, case: str) -> None:
    dirs = _bad_inputs(tmp_path, case)
    out = tmp_path / "rep"
    with pytest.raises(BrlInputError) as err:
        build_report(dirs, out=out)
    assert "\n" not in str(err.value) and str(err.value)
    assert not out.exists()


def test_bad_runs_directory_is_refused(tmp_path: Path) -> None:
    res = write_results(tmp_path / "r", model_set("TGDG"))
    (tmp_path / "empty").mkdir()
    for runs in ([tmp_path / "missing"], [tmp_path / "empty"]):
        with pytest.raises(BrlInputError):
            build_report([res], runs, out=tmp_path / "rep")
    (tmp_path / "imitation" / "seed_0").mkdir(parents=True)  # learning=imitation: no TD learning curve to plot
    (tmp_path / "imitation" / "seed_0" / "iterations.csv").write_text("iteration,driver\n0,expert\n")
    with pytest.raises(BrlInputError, match=r"holds imitation runs .* drop it"):
        build_report([res], [tmp_path / "imitation"], out=tmp_path / "rep")
    with pytest.raises(BrlInputError, match="unknown report format"):
        build_report([res], out=tmp_path / "rep", formats="md,pdf")
    assert not (tmp_path / "rep").exists()


def _brl(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "brlcli.cli", *args], capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize("case", ["mixed suite versions", "corrupt results file", "no results"])
def test_cli_errors_exit_2_on_one_line(tmp_path: Path, case: str) -> None:
    dirs = _bad_inputs(tmp_path, case)
    out = tmp_path / "rep"
    r = _brl("report", *map(str, dirs), "--out", str(out))
    assert r.returncode == 2, r.stderr
    assert r.stderr.startswith("brl: error:") and r.stderr.strip().count("\n") == 0
    assert "Traceback" not in r.stderr
    assert not out.exists()


def test_cli_writes_a_report(tmp_path: Path) -> None:
    res = write_results(tmp_path / "r", model_set("TGDG"))
    out = tmp_path / "rep"
    r = _brl("report", str(res), "--out", str(out), "--format", "md,csv")
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == str(out / "report.md")
    assert "TGDG" in r.stderr and "missing" in r.stderr  # the terminal summary
    assert (out / "report.md").is_file() and (out / "tables" / "paper_test_table.csv").is_file()
    assert not (out / "report.html").exists() and not list(out.rglob("*.tex"))


def test_method_variants_are_model_sets_beside_the_papers(tmp_path: Path) -> None:
    """'TGDG (NAME)' (another method variant) gets its own average and best rows in the TGDG group, before the
    published rows, and is not a baseline."""
    eps = model_set("TGDG") + [{**e, "policy": "v" + e["policy"], "setting": "TGDG (visits)",
                                "frames_file": e["frames_file"].replace("frames/", "frames/v")}
                               for e in model_set("TGDG")]
    out = tmp_path / "rep"
    build_report([write_results(tmp_path / "r", eps)], out=out, formats="csv")
    table = read_csv(out / "tables" / "paper_test_table.csv")
    rows = [(r["Setting"], r["Row"].split(":")[0], r["Source"]) for r in table if r["Setting"].startswith("TGDG")]
    assert rows == [("TGDG", "average", "ours"), ("TGDG", "best model", "ours"),
                    ("TGDG (visits)", "average", "ours"), ("TGDG (visits)", "best model", "ours"),
                    ("TGDG", "average", "published"), ("TGDG", "best model", "published")]


def test_setting_labels_name_the_variant() -> None:
    from brlcli.settings import base_setting, setting_name

    assert setting_name("gt", "estimated") == "TGDE"
    assert setting_name("estimated", "gt", "reference-code") == "TEDG (reference-code)"
    assert base_setting("TEDG (reference-code)") == "TEDG" and base_setting("TGDG") == "TGDG"


def test_results_of_an_older_suite_version_are_read_and_labelled(tmp_path: Path, monkeypatch) -> None:
    from brlcli.bench import suites
    from brlcli.report.load import load_results

    monkeypatch.setitem(suites.SUITE_VERSION, "paper", 2)
    monkeypatch.setitem(suites.SUITE_CHANGES, ("paper", 2), "a test change")
    old = write_results(tmp_path / "old", model_set("TGDG")[:4])
    results = load_results([old])
    assert len(results.episodes) == 4
    assert any("suite version 1, older than this brl's 2 (since then: a test change)" in n for n in results.notes)


def test_nvt_summary_counts_full_runs_on_the_episodes_another_bench_drove(tmp_path: Path) -> None:
    def ep(policy: str, n: int, task: str, success: bool) -> dict:
        return {"suite": "nocrash", "condition": "training", "task": task, "town": "town01", "weather": 1,
                "index": n, "id": f"nocrash/town01/training/{task}/w01/{n:02d}", "policy": policy,
                "setting": policy, "seed": n, "success": success, "km": 0.4, "steps": 100, "collided": not success,
                "crashed": not success, "offroad_steps": 0, "otherlane_steps": 0, "either_steps": 0,
                "frames_file": f"frames/{policy}/{task}{n}.npz"}

    full = [write_results(tmp_path / f"full{s}", [ep(f"set/seed_{s}", n, t, (n + s) % 3 != 0)
                                                  for t in ("dense", "empty") for n in range(6)], suite="nocrash")
            for s in (0, 1)]
    subset = write_results(tmp_path / "sub", [ep("mp", n, t, True) for t in ("dense", "empty") for n in (0, 1)],
                           suite="nocrash")
    script = Path(__file__).resolve().parents[1] / "scripts" / "nvt_summary.py"

    def run(*args: object) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, str(script), *map(str, args)], capture_output=True, text=True)

    whole = run("--seeds", "--conditions", *full)
    assert whole.returncode == 0, whole.stderr
    assert f"{full[0]}: empty 4/6 (2) | dense 4/6 (2)" in whole.stdout  # n = 0, 3 fail for seed 0
    assert "2 seeds: empty 4.0 +- 0.0 (2.0 +- 0.0) of 6 | dense" in whole.stdout
    assert "dense: training 8/12 | all 8/12 = 66.7 %" in whole.stdout
    (tmp_path / "arch").mkdir()
    subprocess.run([sys.executable, str(script.parent / "archive_bench.py"), str(tmp_path / "arch"), str(full[1])],
                   check=True, capture_output=True)
    common = run("--seeds", "--episodes-of", subset, full[0], tmp_path / "arch" / "full1")  # an archive reads too
    assert common.returncode == 0, common.stderr
    assert f"{full[0]}: empty 1/2 (1) | dense 1/2 (1)" in common.stdout  # episodes 0 and 1 only
    assert f"{tmp_path / 'arch' / 'full1'}: empty 2/2 (0)" in common.stdout
    partial = run("--seeds", full[0], subset)
    assert partial.returncode == 2 and partial.stderr.startswith("nvt_summary: error: --seeds needs the same")
    missing = run(tmp_path / "nope")
    assert missing.returncode == 2 and "Traceback" not in missing.stderr and missing.stderr.count("\n") == 1
