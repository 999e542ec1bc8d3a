"""Studies (docs/studies.md): the file and its errors, the stop rule and the early stop, seeds
by point and run, the tables against an independent loop over ``rgtbus.run``, resume after a
kill, the manifest's refusals, the reference check and the plot."""

from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from rgtbus.units.study import (
    TIMED,
    check_reference,
    load_study,
    point_end,
    read_study,
    study,
)

import rgtbus
from rgtbus.cli import main
from rgtbus.errors import RgtbusError
from rgtbus.stats import wilson

ROOT = Path(__file__).resolve().parent.parent

GATE = """
[study]
name = "gate_control"
scenario = "{scenario}"
controller = "d"
target = "a"
steer_to = "open"
failures = {failures}
budget = {budget}
seed = 11

[grid]
repair = [false, true]
noise = [0.0, 0.12, 0.16]
"""

# a study no shipped file resembles: another group (5 units, k = 3 actions), another controller
# and target, an SNR grid
UNSEEN = """
[study]
name = "unseen"
units = 5
alternatives = 3
relations = "drawn"
controller = "u3"
target = "u5"
steer_to = "1"
failures = 4
budget = 10
seed = 2024

[grid]
snr_db = [26.0, 14.0, 8.0]
"""


def gate_file(tmp_path: Path, failures: int = 5, budget: int = 16, name: str = "s.toml") -> Path:
    path = tmp_path / name
    scenario = ROOT / "scenarios" / "gate_goal.toml"
    path.write_text(GATE.format(scenario=scenario, failures=failures, budget=budget))
    return path


def untimed(frame: pd.DataFrame) -> pd.DataFrame:
    return frame.drop(columns=[c for c in TIMED if c in frame.columns])


# -- the file ----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("change", "says"),
    [
        (('steer_to = "open"', 'steer_to = "ajar"'), r":7: steer_to: .*ajar"),
        (('controller = "d"', 'controller = "z"'), r":5: controller: unknown unit 'z'"),
        (('target = "a"', 'target = "d"'), r":6: target: .*not itself"),
        (("noise = [0.0, 0.12, 0.16]", "noise = [0.0, -1.0]"), r":14: noise: must be a σ"),
        (("noise = [0.0, 0.12, 0.16]", "noise = [0.1]\nsnr_db = [3.0]"), r"grid: names one"),
        (("failures = 5", "failures = 0"), r":8: failures: must be an integer 1\.\."),
        (("seed = 11", "seed = 11\nbogus = 1"), r":11: bogus: unknown key"),
        (("repair = [false, true]", 'repair = ["no"]'), r":13: repair: must be a list of true"),
        (("[grid]", '[grid]\n"protocol.schedule" = ["sideways"]'), r"grid: .*sideways"),
    ],
)
def test_a_bad_study_is_one_line_naming_file_line_and_key(tmp_path, change, says):
    path = gate_file(tmp_path)
    path.write_text(path.read_text().replace(*change))
    with pytest.raises(RgtbusError, match=says) as got:
        load_study(path)
    assert "\n" not in str(got.value) and str(path) in str(got.value)


def test_the_command_refuses_a_bad_study_with_exit_2(tmp_path, capsys):
    path = gate_file(tmp_path)
    path.write_text(path.read_text().replace('steer_to = "open"', 'steer_to = "ajar"'))
    assert main(["study", str(path), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "steer_to" in err and "ajar" in err
    assert not (tmp_path / "o").exists()
    assert main(["study", str(gate_file(tmp_path)), "--budget", "0"]) == 2
    assert "--budget" in capsys.readouterr().err


def test_a_point_s_scenario_is_the_base_with_the_controller_s_goal_and_the_point_s_keys(tmp_path):
    st = load_study(gate_file(tmp_path))
    assert [p.label() for p in st.points][:3] == [
        "repair=false, noise=0.0", "repair=false, noise=0.12", "repair=false, noise=0.16"
    ]  # fmt: skip
    sc = st.scenario_of(4, 3)
    assert sc.channel.noise == 0.12 and sc.protocol.repair == "arq"
    assert [(g.unit, g.target) for g in sc.goals] == [("d", "a")]
    assert sc.seed == st.seed_of(4, 3)
    # the run's seed: the run-th child of the point-th child of SeedSequence(seed)
    child = np.random.SeedSequence(11).spawn(5)[4].spawn(4)[3]
    assert st.seed_of(4, 3) == int(child.generate_state(1, np.uint32)[0])
    assert len({st.seed_of(p, r) for p in range(6) for r in range(50)}) == 300


def test_an_snr_grid_gives_sigma_from_the_codebook_s_pulse_amplitude(tmp_path):
    path = tmp_path / "u.toml"
    path.write_text(UNSEEN)
    st = load_study(path)
    words = np.array(list(st.scenario_of(0, 0).codebook.all_words().values()))
    amplitude = float(np.sqrt(np.mean(words**2)))
    for p in st.points:
        assert p.sigma == pytest.approx(amplitude / 10 ** (p.axis_value / 20))
    assert [p.index for p in st.chains()[0]] == [2, 1, 0]  # the hardest channel first


# -- the stop ----------------------------------------------------------------------------------


def test_a_point_stops_at_its_failures_or_its_budget_reading_runs_in_order(tmp_path):
    st = load_study(gate_file(tmp_path, failures=2, budget=5))

    def rows(*steered):
        return {r: {"steered": s} for r, s in enumerate(steered)}

    assert point_end(st, rows(True, False, True, False, False)).runs == 4
    assert point_end(st, rows(True, False, True)) is None  # run 3 is still out
    end = point_end(st, rows(True, True, False, True, True, False))
    assert (end.runs, end.failures, end.stopped) == (5, 1, "budget")
    end = point_end(st, {**rows(False, False), 7: {"steered": False}})
    assert (end.runs, end.stopped) == (2, "failures")


def test_study_tables_equal_an_independent_loop_over_rgtbus_run(tmp_path):
    """The unseen study's points, each from rgtbus.run of the point's scenario file with the
    runs' seeds, stopped by the same rule, give the same counts and intervals."""
    path = tmp_path / "u.toml"
    path.write_text(UNSEEN)
    got = study(path, out=tmp_path / "out", workers=1)
    st = got.study
    assert set(got.points["stopped"]) <= {"failures", "budget", "early"}
    want = rgtbus.load_scenario(st.scenario_of(0, 0)).universe
    steer = want.to_list(want.parse_alternative(st.steer_to))
    early = False
    for chain in st.chains():
        for p in chain:
            row = got.points.set_index("point").loc[p.index]
            if early:
                assert row["stopped"] == "early" and row["runs"] == 0
                continue
            scenario = tmp_path / "out" / "points" / f"point-{p.index:03d}.toml"
            failures = runs = 0
            while runs < st.budget and failures < st.failures:
                r = rgtbus.run(scenario, seed=st.seed_of(p.index, runs))
                unit = r.summary["units"].get("u5") or {}
                ok = r.ok and unit.get("decided") and unit.get("choice") == steer
                failures += not ok
                runs += 1
            assert (row["runs"], row["failures"]) == (runs, failures), p.label()
            k = runs - failures
            assert (row["p_target"], row["p_target_lo"], row["p_target_hi"]) == wilson(k, runs)
            early = failures == 0
    runs = got.runs
    for kind in ("relation", "influence"):  # a symbol error is a misread as another word
        assert (runs[f"{kind}_symbol_errors"] <= runs[f"{kind}_misreads"]).all()
        made = runs.groupby("point")[f"{kind}_decodes"].sum()
        wrong = runs.groupby("point")[f"{kind}_symbol_errors"].sum()
        name = "ser" if kind == "influence" else "relation_ser"
        for p, n in made.items():
            row = got.points.set_index("point").loc[p]
            assert row[name] == (wrong[p] / n if n else None) or (n == 0 and pd.isna(row[name]))
    # every run of the tables re-runs to its row from its point's file and seed
    for run in got.runs.sample(4, random_state=0).to_dict("records"):
        scenario = tmp_path / "out" / "points" / f"point-{run['point']:03d}.toml"
        r = rgtbus.run(scenario, seed=int(run["seed"]))
        choice = r.summary["units"]["u5"]["choice"] if r.ok else None
        assert run["steered"] == (r.ok and choice == steer)
        assert run["sim_seconds"] == r.summary["sim_seconds"]


def test_a_point_with_no_failure_in_its_budget_ends_the_easier_points_of_its_chain(tmp_path):
    got = study(gate_file(tmp_path, failures=3, budget=12), workers=1)
    assert got.out is None  # a temporary directory: only the tables come back
    pts = got.points.set_index(["repair", "noise"])
    # with repair nothing fails at 0.16: 0.12 and 0.0 are not run
    assert pts.loc[(True, 0.16), "stopped"] == "budget"
    assert pts.loc[(True, 0.16), "failures"] == 0
    assert list(pts.loc[(True, 0.12)][["runs", "stopped"]]) == [0, "early"]
    assert list(pts.loc[(True, 0.0)][["runs", "stopped"]]) == [0, "early"]
    assert pd.isna(pts.loc[(True, 0.0), "p_target"])
    # without repair 0.16 fails at once, so 0.12 runs
    assert pts.loc[(False, 0.16), "stopped"] == "failures"
    assert pts.loc[(False, 0.12), "runs"] > 0
    assert len(got.runs) == int(got.points["runs"].sum())


def test_the_tables_do_not_depend_on_the_workers(tmp_path):
    path = gate_file(tmp_path, failures=3, budget=12)
    one = study(path, out=tmp_path / "one", workers=1)
    two = study(path, out=tmp_path / "two", workers=2)
    pd.testing.assert_frame_equal(untimed(one.points), untimed(two.points))
    pd.testing.assert_frame_equal(untimed(one.runs), untimed(two.runs))
    a, b = read_study(tmp_path / "one")
    pd.testing.assert_frame_equal(untimed(a), untimed(read_study(tmp_path / "two")[0]))
    assert len(b) == len(one.runs)


# -- resume ------------------------------------------------------------------------------------


def test_killed_at_any_moment_and_resumed_the_tables_equal_an_uninterrupted_study(
    tmp_path, procs
):
    path = gate_file(tmp_path, failures=400, budget=400)  # more than it can do before the kill
    out = tmp_path / "out"
    p = procs("study", str(path), "--out", str(out), "--workers", "2", "--quiet")
    rows = out / "runs.jsonl"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and p.poll() is None:
        if rows.exists() and rows.read_bytes().count(b"\n") >= 25:
            break
        time.sleep(0.05)
    assert p.poll() is None, "the study ended before it was killed"
    os.kill(p.pid, signal.SIGKILL)
    p.wait(timeout=30)
    kept = rows.read_bytes().count(b"\n")
    with open(rows, "ab") as f:  # a line the kill cut short
        f.write(b'{"point": 0, "run": 99, "stee')
    # resumed with a smaller stop: the runs kept are this stop's first runs too
    assert main(["study", str(path), "--out", str(out), "--resume", "--budget", "12",
                 "--failures", "3", "--workers", "1", "--quiet"]) == 0  # fmt: skip
    info = json.loads((out / "study.json").read_text())
    fresh = study(path, out=tmp_path / "fresh", failures=3, budget=12, workers=1)
    assert info["computed"] < fresh.computed  # what was kept was not run again
    assert info["kept"] == kept + info["computed"]
    points, runs = read_study(out)
    want_points, want_runs = read_study(tmp_path / "fresh")
    pd.testing.assert_frame_equal(untimed(points), untimed(want_points))
    pd.testing.assert_frame_equal(untimed(runs), untimed(want_runs))


def test_json_prints_a_point_a_line_with_nulls_for_points_not_run(tmp_path, capsys):
    path = gate_file(tmp_path, failures=3, budget=12)
    assert main(["study", str(path), "--out", str(tmp_path / "o"), "--json", "--quiet"]) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert len(rows) == 6 and {r["stopped"] for r in rows} >= {"early", "budget"}
    early = next(r for r in rows if r["stopped"] == "early")
    assert early["p_target"] is None and early["runs"] == 0


def test_a_directory_whose_study_never_ran_a_run_is_begun_again(tmp_path, capsys):
    path = gate_file(tmp_path, failures=2, budget=4)
    out = tmp_path / "out"
    assert main(["study", str(path), "--out", str(out), "--scheduler", "tcp://127.0.0.1:9"]) == 2
    assert "cannot reach Dask scheduler" in capsys.readouterr().err
    assert (out / "manifest.json").exists() and not (out / "points.csv").exists()
    assert main(["study", str(path), "--out", str(out), "--workers", "1", "--quiet"]) == 0
    assert read_study(out)[0]["runs"].sum() > 0


def test_resume_refuses_another_study_or_other_versions_in_one_line(tmp_path, capsys):
    path = gate_file(tmp_path, failures=2, budget=4)
    out = tmp_path / "out"
    study(path, out=out, workers=1)
    with pytest.raises(RgtbusError, match="holds a study already: --resume"):
        study(path, out=out, workers=1)
    changed = gate_file(tmp_path, failures=2, budget=4, name="other.toml")
    changed.write_text(changed.read_text().replace("seed = 11", "seed = 12"))
    assert main(["study", str(changed), "--out", str(out), "--resume"]) == 2
    err = capsys.readouterr().err.strip()
    assert "--resume refused" in err and "fingerprint" in err and "\n" not in err
    manifest = json.loads((out / "manifest.json").read_text())
    manifest["versions"]["numpy"] = "0.0.1"
    (out / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(RgtbusError, match=r"made with numpy 0\.0\.1"):
        study(path, out=out, resume=True, workers=1)


# -- the reference check and the plot ----------------------------------------------------------


def test_the_reference_check_fails_when_a_curve_moves_outside_its_interval(tmp_path):
    got = study(gate_file(tmp_path, failures=4, budget=16), workers=1)
    keys = ["repair", "noise"]
    assert check_reference(got.points, got.points, keys) == []
    moved = got.points.copy()
    row = moved.index[(moved["runs"] > 0) & (moved["failures"] == 0)][0]
    moved.loc[row, "failures"] = moved.loc[row, "runs"]  # every run now fails: p 1 -> 0
    bad = check_reference(moved, got.points, keys)
    assert len(bad) == 1 and "outside the reference's" in bad[0]
    assert check_reference(got.points, got.points[got.points["repair"]], keys)


def test_study_plot_draws_png_and_svg(tmp_path, capsys):
    out = tmp_path / "out"
    study(gate_file(tmp_path, failures=2, budget=6), out=out, workers=1)
    assert main(["study-plot", str(out)]) == 0
    for suffix in ("png", "svg"):
        path = out / f"study.{suffix}"
        assert path.stat().st_size > 1000
    assert (out / "study.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert b"<svg" in (out / "study.svg").read_bytes()[:1000]
    capsys.readouterr()
    assert main(["study-plot", str(out), "-o", str(tmp_path / "f"), "--json"]) == 0
    said = json.loads(capsys.readouterr().out)
    assert said["outputs"] == [str(tmp_path / "f.png"), str(tmp_path / "f.svg")]
    assert main(["study-plot", str(tmp_path / "nothing")]) == 2


def test_shipped_studies_are_listed_and_load_by_name(capsys):
    assert main(["studies"]) == 0
    names = capsys.readouterr().out
    for name in ("control_gate", "control_group10", "control_scaling"):
        assert name in names
        st = load_study(name)
        assert st.points and st.failures >= 50


def test_crossings_interpolate_where_each_curve_falls_below_the_level():
    from rgtbus.units.study import crossings

    points = pd.DataFrame(
        {
            "repair": [False, False, False, True, True],
            "noise": [0.0, 0.1, 0.2, 0.1, 0.2],
            "runs": [10, 10, 10, 10, 10],
            "p_target": [1.0, 0.95, 0.45, 1.0, 0.95],
            "p_target_lo": [0.9, 0.85, 0.2, 0.9, 0.85],
            "p_target_hi": [1.0, 1.0, 0.7, 1.0, 1.0],
        }
    )
    got = crossings(points, ["repair", "noise"]).set_index("repair")
    assert got.loc[False, "crossing"] == pytest.approx(0.11)  # 0.95 -> 0.45 over 0.1..0.2
    assert got.loc[False, "earliest"] == pytest.approx(0.0)  # the lower end starts at 0.9
    assert got.loc[False, "latest"] == pytest.approx(0.1 + 0.1 * 0.1 / 0.3)
    assert pd.isna(got.loc[True, "crossing"]) and pd.isna(got.loc[True, "latest"])
    assert got.loc[True, "earliest"] == pytest.approx(0.1)
    snr = points.rename(columns={"noise": "snr_db"}).assign(snr_db=[30.0, 20.0, 10.0, 20.0, 10.0])
    got = crossings(snr, ["repair", "snr_db"]).set_index("repair")
    assert got.loc[False, "crossing"] == pytest.approx(20.0 - 10.0 * 0.05 / 0.5)


def test_a_family_s_bad_relations_and_a_bad_grid_value_name_their_key(tmp_path):
    path = tmp_path / "f.toml"
    path.write_text(UNSEEN.replace('relations = "drawn"', 'relations = {"u1>u2" = "ally"}'))
    with pytest.raises(RgtbusError, match=r":6: relations: relations\.fixed\.u1>u2: must be"):
        load_study(path)
    path.write_text(UNSEEN.replace("[grid]", '[grid]\n"channel.gain" = [{"u1>zz" = 0.5}]'))
    with pytest.raises(RgtbusError, match=r"grid: at channel\.gain=.*unknown unit 'zz'"):
        load_study(path)


def test_a_row_changed_after_it_was_written_is_no_finished_run(tmp_path):
    path = gate_file(tmp_path, failures=3, budget=8)
    out = tmp_path / "out"
    first = study(path, out=out, workers=1)
    rows = out / "runs.jsonl"
    lines = rows.read_text().splitlines(keepends=True)
    row = json.loads(lines[3])
    row["steered"] = not row["steered"]  # its checksum no longer holds
    lines[3] = json.dumps(row, sort_keys=True) + "\n"
    rows.write_text("".join(lines))
    again = study(path, out=out, workers=1, resume=True)
    assert again.computed == 1 and any("not whole" in n for n in again.notes)
    pd.testing.assert_frame_equal(untimed(again.points), untimed(first.points))
    assert all(json.loads(x)["_sha256"] for x in rows.read_text().splitlines())


def test_a_table_valued_axis_is_json_text_in_the_tables_and_plots(tmp_path, capsys):
    path = gate_file(tmp_path, failures=2, budget=4)
    path.write_text(path.read_text().replace(
        "repair = [false, true]", '"channel.gain" = [{}, {"d>a" = 0.5}]'
    ))  # fmt: skip
    out = tmp_path / "out"
    assert main(["study", str(path), "--out", str(out), "--workers", "1", "--quiet"]) == 0
    said = capsys.readouterr().out.splitlines()
    assert sum(line.startswith("p_target ") for line in said) == 2  # a crossing a curve
    points, runs = read_study(out)
    assert list(points["channel.gain"].unique()) == ["{}", '{"d>a": 0.5}']
    assert set(runs["channel.gain"]) <= {"{}", '{"d>a": 0.5}'}
    assert main(["study-plot", str(out)]) == 0
    assert check_reference(points, points, ["channel.gain", "noise"]) == []
