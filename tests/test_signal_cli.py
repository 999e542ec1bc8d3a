"""``rgtbus resonate`` and ``rgtbus figures``: outputs and refusals (exit 2, one line)."""

import json
import re
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
        (["--duration", "1e6"], "beyond the budget of 2e+07"),  # 2e8 resonator-samples
        (["--duration", "1e30"], "beyond 1e+09 s"),
        (["--pulses=" + ",".join(["0.5"] * 2_000_000)], "beyond the budget"),
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


# -- figures: captions say what was run, π not pi -------------------------------------------


def _ascii_pi(texts) -> list[str]:
    """Texts that write π as "pi" (3pi/2, pi), not counting words such as "spike"."""
    return [t for t in texts if re.search(r"(?<![a-z])pi(?![a-z])", t)]


def _texts(fig) -> list[str]:
    """Every piece of text a figure shows: titles, labels, ticks, legends, free text."""
    out = [t.get_text() for t in fig.texts]
    if fig._suptitle is not None:
        out.append(fig._suptitle.get_text())
    for ax in fig.axes:
        out += [ax.get_title(loc=x) for x in ("left", "center", "right")]
        out += [ax.get_xlabel(), ax.get_ylabel()]
        out += [t.get_text() for t in ax.get_xticklabels() + ax.get_yticklabels()]
        out += [t.get_text() for t in ax.texts]
        if ax.get_legend() is not None:
            out += [t.get_text() for t in ax.get_legend().get_texts()]
    return [t for t in out if t]


@pytest.fixture
def saved(monkeypatch):
    """The figures and captions ``signal_cmds`` saves (still written to disk)."""
    from rgtbus.cli import signal_cmds

    got = []
    real = signal_cmds._save

    def spy(fig, path, caption):
        got.append((fig, caption))
        real(fig, path, caption)

    monkeypatch.setattr(signal_cmds, "_save", spy)
    return got


def test_resonate_plot_title_and_caption_state_the_noise(tmp_path, capsys, saved):
    png = tmp_path / "r.png"
    argv = ["resonate", "--noise", "0.05", "--seed", "7", "--plot", str(png)]
    assert run(argv, capsys)[0] == 0
    ((fig, caption),) = saved
    texts = _texts(fig)
    assert fig._suptitle.get_text().startswith(
        "Resonators fed the code {0.4, 0.4, 0.4} on ω = 3π/2"
    )
    assert "σ = 0.05" in fig._suptitle.get_text()
    assert "σ = 0.05" in caption and "seed 7" in caption and "paper mode" in caption
    assert not _ascii_pi(texts) and any("3π/2" in t for t in texts)
    saved.clear()
    assert run(["resonate", "--plot", str(png)], capsys)[0] == 0
    assert "no noise (σ = 0)" in saved[0][1]


def test_resonate_text_prints_the_code_in_braces(capsys):
    code, out, _ = run(["resonate", "--pulses=0.1,0.4,0.6"], capsys)
    assert code == 0 and out.startswith("code {0.1, 0.4, 0.6} on 3pi/2") and "[" not in out


def test_pair_and_ser_figures_write_pi(tmp_path, saved):
    from rgtbus.cli.signal_cmds import figure_pair, figure_ser

    caption = figure_pair(tmp_path / "p.png", (0, 2), (0.4, 0.4, 0.4), "Excitatory, 3π/2 vs 5π/3")
    figure_ser(tmp_path / "s.png", trials=5, seed=0)
    assert "ω = 3π/2 fires for its own series" in caption
    for fig, cap in saved:
        texts = [*_texts(fig), cap]
        assert not _ascii_pi(texts) and any("π" in t for t in texts)


def test_receiving_paper_claim_holds_at_rest_and_ringing_reverses_it():
    from rgtbus.cli.signal_cmds import receiving_run

    def late(run):  # channels that spike on the ω_c code
        return {c for c, ts in run.spikes.items() if any(t >= run.t_send for t in ts)}

    rest, ringing = receiving_run(quench=True), receiving_run(quench=False)
    assert rest.spikes["a"][0] == ringing.spikes["a"][0] == 2.67  # a's ID fires ω_a alone
    assert rest.t_send == ringing.t_send == 3.17  # 0.5 s after it
    assert late(rest) == {"c"} and rest.spikes["c"] == [5.57]  # the paper's outcome
    assert late(ringing) == {"b"} and ringing.spikes["b"] == [4.37]  # ours, in a turn
    # Without the quench only a window of delays gives the paper's outcome (docs/model.md).
    for delay, paper in [(0.5, False), (0.845, False), (0.85, True), (1.08, True), (1.085, False)]:
        assert (late(receiving_run(quench=False, delay=delay)) == {"c"}) is paper, delay


def test_receiving_figure_shows_both_and_says_which_is_which(tmp_path, saved):
    from rgtbus.cli.signal_cmds import figure_receiving

    caption = figure_receiving(tmp_path / "receiving.png")
    ((fig, _),) = saved
    texts = _texts(fig)
    assert len(fig.axes) == 6
    assert "ω_c spikes at 5.57 s, ω_b no spike, ω_a no spike, the paper's outcome" in caption
    assert "ω_c no spike, ω_b spikes at 4.37 s, ω_a no spike, not the paper's outcome" in caption
    assert any(t.startswith("Paper's claim: bank at rest") for t in texts)
    assert any(t.startswith("rgtbus default (a protocol turn): no quench") for t in texts)
    assert not _ascii_pi(texts) and any("5π/3" in t for t in texts)
