"""The shipped studies against their reference curves (scenarios/studies/NAME.csv, made by the
full study: docs/studies.md), and a study on a Dask cluster. Longer checks: CI's slow pass.

A reduced study runs the same points with the same seeds and a smaller stop, so its runs are the
reference's first runs; each point must agree with the reference's (``check_reference``: their
99.9 % Wilson intervals overlap), and a curve moved outside its interval must not."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest
from rgtbus.units.study import TIMED, check_reference, study

from rgtbus.telemetry.study_plot import grid_columns

ROOT = Path(__file__).resolve().parent.parent
STUDIES = ROOT / "scenarios" / "studies"
# a reduced stop per shipped study: a few minutes on two cores for both
REDUCED = {"control_gate": (25, 120), "control_group10": (15, 50)}


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(REDUCED))
def test_a_reduced_study_falls_inside_its_reference_curve(name):
    reference = pd.read_csv(STUDIES / f"{name}.csv")
    failures, budget = REDUCED[name]
    got = study(name, failures=failures, budget=budget, workers=2)
    keys = grid_columns(got.points)
    assert keys == grid_columns(reference)
    assert (got.points["runs"] <= budget).all() and got.points["runs"].sum() > 0
    assert check_reference(got.points, reference, keys) == []
    # the same check fails the curve moved to the other end of [0, 1] at every point
    moved = got.points.copy()
    run = moved["runs"] > 0
    moved.loc[run, "failures"] = moved.loc[run].apply(
        lambda r: r["runs"] if r["p_target"] > 0.5 else 0, axis=1
    )
    bad = check_reference(moved, reference, keys)
    assert len(bad) == int(run.sum()) > 0


@pytest.mark.slow
def test_the_same_tables_on_a_dask_local_cluster(tmp_path):
    distributed = pytest.importorskip("distributed")
    spec = {
        "study": {"name": "dask", "scenario": "gate_goal", "controller": "d", "target": "a",
                  "steer_to": "open", "failures": 3, "budget": 10},
        "grid": {"repair": [False, True], "noise": [0.0, 0.14]},
    }  # fmt: skip
    pool = study(spec, workers=2)
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster:
        dask = study(spec, scheduler=cluster.scheduler_address)
    drop = [c for c in TIMED if c in pool.points.columns]
    pd.testing.assert_frame_equal(pool.points.drop(columns=drop), dask.points.drop(columns=drop))
    drop = [c for c in TIMED if c in pool.runs.columns]
    pd.testing.assert_frame_equal(pool.runs.drop(columns=drop), dask.runs.drop(columns=drop))
