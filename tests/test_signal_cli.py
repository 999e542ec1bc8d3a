"""``rgtbus resonate`` and ``rgtbus figures``: outputs and refusals (exit 2, one line)."""

import json
import subprocess
import sys

import pytest

from rgtbus.cli import main


def run(argv, capsys):
    try:
        code = main(argv)
    except SystemExit as e:  # argparse usage errors
        code = e.code
    out = capsys.readouterr()
    return code, out.out, out.err


def test_resonate_text_paper_id_code(capsys):
    code, out, _ = run(
        [
            "resonate",
            "--omega",
            "3pi/2",
            "--omega",
            "4pi/3",
            "--omega",
            "5pi/3",
            "--pulses=0.4,0.4,0.4",
            "--on",
            "0",
        ],
        capsys,
    )
    assert code == 0
    lines = out.splitlines()
    assert "3pi/2" in lines[2] and "1.500" in lines[2] and "2.670" in lines[2]
    assert lines[3].rstrip().endswith("-") and lines[4].rstrip().endswith("-")


def test_resonate_json_shows_crosstalk(capsys):
    code, out, _ = run(["resonate", "--pulses=0.2,0.3,0.7", "--on", "2", "--json"], capsys)
    assert code == 0
    data = json.loads(out)
    res = data["resonators"]
    assert [round(r["omega"], 4) for r in res] == [4.7124, 4.1888, 5.2360]
    assert res[0]["spikes"] and res[2]["spikes"] and not res[1]["spikes"]  # a<->c crosstalk
    assert res[0]["peak_y"] == 1.5 and res[1]["peak_y"] < 1
    assert set(res[0]) == {"omega", "peak_y", "spikes"}


def test_resonate_noise_is_seeded_and_exact_mode(capsys):
    argv = [
        "resonate",
        "--noise",
        "0.05",
        "--seed",
        "7",
        "--json",
        "--mode",
        "exact",
        "--omega",
        "12",
        "--omega",
        "1.5pi",
        "--start",
        "0.2",
    ]
    a = run(argv, capsys)[1]
    b = run(argv, capsys)[1]
    assert a == b and json.loads(a)["resonators"][0]["omega"] == 12.0


def test_resonate_plot(tmp_path, capsys):
    png = tmp_path / "r.png"
    code, _, _ = run(["resonate", "--pulses=-0.4,-0.4,-0.4", "--plot", str(png)], capsys)
    assert code == 0 and png.read_bytes()[:4] == b"\x89PNG"


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["--omega", "3pi/x"], "'3pi/x'"),
        (["--omega", "2.1pi"], "beyond Euler's stable band"),
        (["--pulses=0.4,zz"], "'zz'"),
        (["--pulses=0.4,nan"], "not finite"),
        (["--on", "3"], "--on 3"),
        (["--start", "-1"], "--start"),
        (["--noise", "-0.1"], "--noise"),
        (["--duration", "1"], "after the end"),
        (["--duration", "0"], "--duration"),
        (["--mode", "fast"], "invalid choice"),
        (["--plot", "/proc/nope/x.png"], "cannot write"),
    ],
)
def test_resonate_refusals(argv, needle, capsys):
    code, out, err = run(["resonate", *argv], capsys)
    assert code == 2 and out == ""
    assert needle in err and len(err.strip().splitlines()) == 1


def test_figures_refusals(tmp_path, capsys):
    f = tmp_path / "file"
    f.write_text("x")
    code, _, err = run(["figures", str(f)], capsys)
    assert code == 2 and "not a directory" in err
    code, _, err = run(["figures", str(tmp_path), "--trials", "0"], capsys)
    assert code == 2 and "--trials" in err


def test_refusal_has_no_traceback():
    p = subprocess.run(
        [sys.executable, "-m", "rgtbus", "resonate", "--omega", "pi/0"],
        capture_output=True,
        text=True,
        check=False,
    )
    assert p.returncode == 2 and "Traceback" not in p.stderr
    assert p.stderr.strip() == "rgtbus resonate: error: --omega: 'pi/0' divides by zero"


@pytest.mark.slow
def test_figures_writes_every_png(tmp_path, capsys):
    code, out, _ = run(["figures", str(tmp_path / "figs"), "--trials", "60"], capsys)
    assert code == 0
    pngs = sorted((tmp_path / "figs").glob("*.png"))
    assert len(pngs) == 10 and all(p.read_bytes()[:4] == b"\x89PNG" for p in pngs)
    assert len(out.splitlines()) == 10 and all(": " in line for line in out.splitlines())
    assert "fires for its own series" in out
