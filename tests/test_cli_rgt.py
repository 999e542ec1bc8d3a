"""``rgtbus solve`` and ``rgtbus control``: the paper's examples and every error path."""

import json
import subprocess
import sys

import pytest

from rgtbus.cli import main

OVERVIEW = [
    "--influence",
    "a>b={alpha}",
    "--influence",
    "a>c={beta}",
    "--influence",
    "b>a={beta}",
    "--influence",
    "b>c={beta}",
    "--influence",
    "c>a={beta}",
    "--influence",
    "c>b={beta}",
]


def run_json(capsys, *argv):
    assert main([*argv, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_solve_overview_a_times_b_plus_c(capsys):
    out = run_json(capsys, "solve", "a(b+c)", "--actions", "alpha,beta", *OVERVIEW)
    assert out["polynomial"] == "a(b+c)"
    assert out["folded"] == "a(b+c)+not(a)"
    a, b, c = (out["subjects"][s] for s in "abc")
    assert a["frustrated"] and a["interval"] is None and a["choices"] == []
    assert a["A"] == ["beta"] and a["B"] == ["alpha", "beta"]
    assert b["interval"] == [["beta"], ["alpha", "beta"]]
    assert b["choices"] == [["beta"], ["alpha", "beta"]]
    assert c["interval"] == [["alpha", "beta"], ["alpha", "beta"]] and not c["frustrated"]


def test_solve_overview_ab_plus_c_via_alliances(capsys):
    out = run_json(
        capsys,
        "solve",
        "--alliance",
        "a-b",
        "--subjects",
        "a,b,c",
        "--actions",
        "alpha,beta",
        *OVERVIEW,
    )
    assert out["polynomial"] == "ab+c" and out["folded"] == "ab+c"
    assert out["subjects"]["a"]["interval"] == [["beta"], ["beta"]]
    assert out["subjects"]["b"]["interval"] == [["beta"], ["alpha", "beta"]]
    assert out["subjects"]["c"]["interval"] == [["beta"], ["alpha", "beta"]]
    assert out["subjects"]["a"]["canonical"] == "a = (b+c)a + c·not(a)"


def test_solve_example1_and_example2(capsys):
    out = run_json(
        capsys,
        "solve",
        "--alliance",
        "b-c",
        "--subjects",
        "a,b,c",
        "--actions",
        "alpha,beta",
        "--influence",
        "a>b={alpha}",
        "--influence",
        "a>c={}",
        "--influence",
        "b>a={alpha}",
        "--influence",
        "b>c={beta}",
        "--influence",
        "c>a={beta}",
        "--influence",
        "c>b=0",
    )
    assert out["polynomial"] == "a+bc"  # Example 1's group
    subjects = out["subjects"]
    assert subjects["a"]["interval"] == [[], ["alpha", "beta"]]
    assert subjects["b"]["interval"] == [["alpha"], ["alpha"]]
    assert subjects["c"]["interval"] == [[], ["beta"]]
    assert subjects["c"]["choices"] == [[], ["beta"]]


def test_solve_example3_gate_text(capsys):
    inf = [f"--influence={s}>{d}=0" for s in "abc" for d in "abcd" if s != d]
    inf += [f"--influence=d>{x}=1" for x in "abc"]
    assert main(["solve", "abc+d", "--actions", "open", *inf]) == 0
    text = capsys.readouterr().out
    assert "F = abc+d" in text
    assert "a = (bc+d)a + d·not(a)" in text and "A = B = 1: a = 1" in text
    assert "b = (ac+d)b + d·not(b)" in text
    assert "interval 1 ⊇ d ⊇ 0: choices 0, 1" in text
    assert "[abc+d]" in text  # the diagonal form


def test_solve_symbolic(capsys):
    assert main(["solve", "(a+b)c+d", "--actions", "x", "--symbolic"]) == 0
    text = capsys.readouterr().out
    assert "F = c+d" in text and "c = c + d·not(c)" in text


def test_control_paper_inverse_task(capsys):
    out = run_json(
        capsys,
        "control",
        "ab+c",
        "--actions",
        "alpha,beta",
        "--subject",
        "a",
        "--target",
        "{alpha}",
    )
    assert out["subject"] == "a" and out["target"] == ["alpha"] and out["mode"] == "exact"
    assert out["count"] == 2
    assert sorted(map(json.dumps, out["solutions"])) == sorted(
        map(json.dumps, [{"b": ["alpha"], "c": ["alpha"]}, {"b": [], "c": ["alpha"]}])
    )


def test_control_count_only_interval_fixed_and_brute_force(capsys):
    out = run_json(
        capsys,
        "control",
        "ab+c",
        "--actions",
        "alpha,beta",
        "--subject",
        "a",
        "--target",
        "[{beta},1]",
        "--mode",
        "contains",
        "--count-only",
    )
    assert "solutions" not in out and out["target"] == [["beta"], ["alpha", "beta"]]
    brute = run_json(
        capsys,
        "control",
        "ab+c",
        "--actions",
        "alpha,beta",
        "--subject",
        "a",
        "--target",
        "[{beta},1]",
        "--mode",
        "contains",
        "--brute-force",
    )
    assert brute["count"] == out["count"] == len(brute["solutions"])
    fixed = run_json(
        capsys,
        "control",
        "abc+d",
        "--actions",
        "open",
        "--subject",
        "a",
        "--target",
        "1",
        "--influence",
        "b>a=0",
        "--influence",
        "c>a=0",
    )
    assert fixed["solutions"] == [{"b": [], "c": [], "d": ["open"]}]


def test_control_limit_truncates(capsys):
    out = run_json(
        capsys,
        "control",
        "abcde+f",
        "--actions",
        "p,q",
        "--subject",
        "f",
        "--target",
        "1",
        "--mode",
        "contains",
        "--limit",
        "5",
    )
    assert out["count"] == 4**5 and len(out["solutions"]) == 5 and out["truncated"]
    assert (
        main(
            [
                "control",
                "abcde+f",
                "--actions",
                "p,q",
                "--subject",
                "f",
                "--target",
                "1",
                "--mode",
                "contains",
                "--limit",
                "5",
            ]
        )
        == 0
    )
    assert "1019 more" in capsys.readouterr().out


ERRORS = [
    (["solve", "ab+c", "--actions", "alpha,beta", "--influence", "a>b={gamma}"], "'gamma'"),
    (
        ["solve", "ab+c", "--actions", "alpha,beta", "--influence", "a>b={alpha}"],
        "missing influence b>a (on subject a)",
    ),
    (["solve", "a+", "--actions", "x"], "end of input"),
    (["solve", "a1b", "--actions", "x"], "'1'"),
    (
        ["solve", "--alliance", "a-b,b-c,c-d", "--subjects", "a,b,c,d", "--actions", "x"],
        "induced P4 a-b-c-d",
    ),
    (["solve", "--alliance", "a-b-c", "--subjects", "a,b,c", "--actions", "x"], "'a-b-c'"),
    (["solve", "--alliance", "a-z", "--subjects", "a,b", "--actions", "x"], "'z'"),
    (["solve", "ab", "--alliance", "a-b", "--actions", "x"], "not both"),
    (["solve", "--actions", "x"], "give the group"),
    (["solve", "ab", "--actions", "x,x"], "'x' is listed twice"),
    (["solve", "ab", "--actions", "x,"], "empty action name"),
    (["solve", "ab", "--actions", "x", "--influence", "a=b>1"], "bad influence"),
    (["solve", "ab", "--actions", "x", "--symbolic", "--influence", "a>b=1"], "--symbolic"),
    (["solve", "ab"], "--actions"),
    (["control", "ab+c", "--actions", "alpha,beta", "--subject", "z", "--target", "1"], "'z'"),
    (["control", "ab+c", "--actions", "alpha,beta", "--subject", "a", "--target", "{x}"], "'x'"),
    (
        [
            "control",
            "ab+c",
            "--actions",
            "alpha,beta",
            "--subject",
            "a",
            "--target",
            "[{alpha},{beta}]",
        ],
        "is empty",
    ),
    (
        ["control", "ab+c", "--actions", "alpha,beta", "--subject", "a", "--target", "[1]"],
        "bad interval",
    ),
    (
        [
            "control",
            "ab+c",
            "--actions",
            "alpha,beta",
            "--subject",
            "a",
            "--target",
            "1",
            "--influence",
            "b>c=1",
        ],
        "does not act on the controlled subject a",
    ),
    (
        [
            "control",
            "ab+c",
            "--actions",
            "alpha,beta",
            "--subject",
            "a",
            "--target",
            "1",
            "--mode",
            "maybe",
        ],
        "'maybe'",
    ),
    (
        [
            "control",
            "ab+c",
            "--actions",
            "alpha,beta",
            "--subject",
            "a",
            "--target",
            "1",
            "--limit",
            "0",
        ],
        "'0'",
    ),
    (
        [
            "control",
            "abcdefghijkl",
            "--actions",
            "p,q,r",
            "--subject",
            "a",
            "--target",
            "1",
            "--brute-force",
        ],
        "brute force needs",
    ),
    (["frobnicate"], "invalid choice"),
]


@pytest.mark.parametrize(("argv", "needle"), ERRORS, ids=[" ".join(a)[:60] for a, _ in ERRORS])
def test_errors_one_line_exit_2(capsys, argv, needle):
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse usage errors
        code = exc.code
    captured = capsys.readouterr()
    assert code == 2
    assert captured.out == ""
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1, captured.err
    assert needle in lines[0]


def test_console_script_no_traceback():
    proc = subprocess.run(
        [sys.executable, "-m", "rgtbus", "solve", "a(b+c", "--actions", "x"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    assert proc.stderr.strip() == (
        "rgtbus solve: error: missing ')' for '(' at position 1 in 'a(b+c'"
    )


def test_control_beyond_sixteen_subjects_is_refused_by_rule(capsys):
    poly = "+".join(chr(97 + i) for i in range(17))  # a+b+...+q
    code = main(["control", poly, "--subject", "a", "--target", "1", "--actions", "alpha"])
    out, err = capsys.readouterr()
    assert code == 2 and out == "" and err.count("\n") == 1
    assert "2^17 entries: built only for groups of at most 16" in err
