"""``rgtbus solve`` (forward task) and ``rgtbus control`` (inverse task)."""

from __future__ import annotations

import argparse
import json
from typing import TYPE_CHECKING, Any

from rgtbus.cli import add_quiet_argument
from rgtbus.cli.tables import fitted_table_lines, wrapped_table_lines
from rgtbus.errors import BadInput
from rgtbus.rgt import (
    DecisionFunction,
    InfluenceMatrix,
    RelationGraph,
    Universe,
    canonical_forms,
    decision_function,
    diagonal_text,
    format_expr,
    forward,
    graph_to_polynomial,
    parse_polynomial,
    solve_brute_force,
    solve_per_action,
)
from rgtbus.rgt.expr import Expr, needs_star

if TYPE_CHECKING:
    from rgtbus.cli import SubParsers


def register(subparsers: SubParsers) -> None:
    """Add ``solve`` and ``control``."""
    solve = subparsers.add_parser(
        "solve",
        help="forward task: canonical forms, intervals and frustration for every subject",
        description="Forward task of Reflexive Game Theory for a group given as a polynomial "
        "(e.g. 'ab+c') or as alliances over subjects.",
    )
    _group_arguments(solve)
    solve.add_argument(
        "--influence",
        action="append",
        default=[],
        metavar="SRC>DST=VALUE",
        help="influence of SRC on DST, e.g. 'a>b={alpha}'; every ordered pair is needed",
    )
    solve.add_argument(
        "--symbolic",
        action="store_true",
        help="print the structure and symbolic canonical forms only (no influences)",
    )
    solve.add_argument("--json", action="store_true", help="print one JSON object")
    add_quiet_argument(solve)
    solve.set_defaults(func=run_solve)

    control = subparsers.add_parser(
        "control",
        help="inverse task: every joint influence that makes a subject choose a target",
        description="Inverse task (reflexive control), solved per action.",
    )
    _group_arguments(control)
    control.add_argument("--subject", required=True, help="the controlled subject")
    control.add_argument(
        "--target",
        required=True,
        help="an alternative ({alpha}, 1, 0, ...) or an interval '[{beta},1]'",
    )
    control.add_argument(
        "--mode",
        choices=("exact", "contains"),
        default="exact",
        help="exact: the interval is the target; contains: the target lies in it",
    )
    control.add_argument(
        "--influence",
        action="append",
        default=[],
        metavar="SRC>DST=VALUE",
        help="a fixed influence on the controlled subject",
    )
    control.add_argument("--count-only", action="store_true", help="count, do not list")
    control.add_argument(
        "--limit",
        type=_positive_int,
        default=1000,
        help="list at most this many solutions (default 1000)",
    )
    control.add_argument(
        "--brute-force",
        action="store_true",
        help="enumerate whole alternatives instead of solving per action",
    )
    control.add_argument("--json", action="store_true", help="print one JSON object")
    add_quiet_argument(control)
    control.set_defaults(func=run_control)


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1: {text!r}")
    return value


def _group_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("poly", nargs="?", metavar="POLY", help="the group's polynomial, e.g. 'a(b+c)'")
    p.add_argument("--actions", required=True, help="the universal set, e.g. alpha,beta")
    p.add_argument(
        "--alliance",
        metavar="PAIRS",
        help="instead of POLY: alliances like a-b,a-c (all other pairs are conflicts)",
    )
    p.add_argument("--subjects", metavar="NAMES", help="with --alliance: every subject, e.g. a,b,c")


def _split_names(text: str, what: str) -> list[str]:
    names = [p.strip() for p in text.split(",")]
    if any(not n for n in names):
        raise BadInput(f"empty name in {what} {text!r}")
    return names


def load_group(args: argparse.Namespace) -> tuple[Expr, DecisionFunction, Universe]:
    """The group the options give (POLY, or ``--subjects`` with ``--alliance``): its
    polynomial, decision function and universe of actions."""
    universe = Universe.parse(args.actions)
    if args.poly is not None and (args.alliance is not None or args.subjects is not None):
        raise BadInput("give either POLY or --alliance/--subjects, not both")
    if args.poly is not None:
        poly = parse_polynomial(args.poly)
        return poly, decision_function(poly), universe
    if args.subjects is None:
        raise BadInput("give the group: POLY, or --subjects (with --alliance)")
    subjects = _split_names(args.subjects, "--subjects")
    pairs = []
    if args.alliance:
        for item in _split_names(args.alliance, "--alliance"):
            parts = item.split("-")
            if len(parts) != 2 or not all(parts):
                raise BadInput(f"bad alliance {item!r} in --alliance: write a-b")
            pairs.append((parts[0].strip(), parts[1].strip()))
    graph = RelationGraph.from_pairs(subjects, pairs)
    poly = graph_to_polynomial(graph)
    return poly, decision_function(poly, subjects), universe


def _alt_json(universe: Universe, mask: int) -> list[str]:
    return universe.to_list(mask)


def run_solve(args: argparse.Namespace) -> int:
    """``rgtbus solve``: canonical forms, and with the influences every subject's interval,
    choices or frustration."""
    poly, df, universe = load_group(args)
    star = needs_star(df.order)
    forms = canonical_forms(df)
    results = None
    if not args.symbolic:
        matrix = InfluenceMatrix.parse(args.influence, df.order, universe)
        results = forward(df, universe, matrix)
    elif args.influence:
        raise BadInput("--symbolic takes no --influence")

    if args.json:
        out: dict[str, Any] = {
            "polynomial": format_expr(poly, star),
            "folded": df.text(),
            "actions": list(universe.actions),
            "subjects": {},
        }
        for s in df.order:
            entry: dict[str, Any] = {
                "canonical": forms[s].text(star),
                "A_expr": format_expr(forms[s].A, star),
                "B_expr": format_expr(forms[s].B, star),
            }
            if results is not None:
                r = results[s]
                entry.update(
                    A=_alt_json(universe, r.A),
                    B=_alt_json(universe, r.B),
                    frustrated=r.frustrated,
                    interval=None
                    if r.frustrated
                    else [_alt_json(universe, r.B), _alt_json(universe, r.A)],
                    choices=[_alt_json(universe, c) for c in r.choices(universe)],
                )
            out["subjects"][s] = entry
        print(json.dumps(out))
        return 0

    print(f"polynomial: {format_expr(poly, star)}")
    print(f"actions:    {', '.join(universe.actions)}  (1 = all, 0 = none)")
    print("diagonal form:")
    for line in diagonal_text(poly, df.display).splitlines():
        print(f"  {line}")
    print(f"F = {df.text()}")
    if results is not None:
        print("influences (row influences column):")
        print(_matrix_text(df, universe, InfluenceMatrix.parse(args.influence, df.order, universe)))
    print("subjects:")
    rows = []
    for s in df.order:
        row = [forms[s].text(star)]
        if results is not None:
            r = results[s]
            a, b = universe.format(r.A), universe.format(r.B)
            if r.frustrated:
                verdict = f"A = {a}, B = {b}: frustrated (B not within A), no decision"
            elif r.A == r.B:
                verdict = f"A = B = {a}: {s} = {a}"
            else:
                choices = ", ".join(universe.format(c) for c in r.choices(universe))
                verdict = f"interval {a} ⊇ {s} ⊇ {b}: choices {choices}"
            row.append(verdict)
        rows.append(row)
    for line in fitted_table_lines(rows):
        print(line)
    return 0


def _matrix_text(df: DecisionFunction, universe: Universe, matrix: InfluenceMatrix) -> str:
    rows = []
    for src in df.order:
        row = [src]
        for dst in df.order:
            v = matrix.get(src, dst)
            row.append(dst if src == dst else universe.format(v) if v is not None else "?")
        rows.append(row)
    return "\n".join(wrapped_table_lines(rows, ["", *df.order]))


def run_control(args: argparse.Namespace) -> int:
    """``rgtbus control``: the joint influences that make the subject choose the target
    (counted; listed up to ``--limit``)."""
    poly, df, universe = load_group(args)
    star = needs_star(df.order)
    subject = args.subject
    df.index(subject)
    lo, hi = universe.parse_interval(args.target)
    matrix = InfluenceMatrix.parse(args.influence, df.order, universe)
    fixed = {}
    for (src, dst), v in matrix.items():
        if dst != subject:
            raise BadInput(
                f"influence {src}>{dst} does not act on the controlled subject {subject}"
            )
        fixed[src] = v
    if args.brute_force:
        found = solve_brute_force(df, universe, subject, lo, hi, args.mode, fixed)
        count = len(found)
        listed = [] if args.count_only else found[: args.limit]
    else:
        result = solve_per_action(df, universe, subject, lo, hi, args.mode, fixed)
        count = result.count
        listed = [] if args.count_only else list(result.solutions(args.limit))
    truncated = not args.count_only and count > len(listed)

    target_json: Any = (
        universe.to_list(lo) if lo == hi else [universe.to_list(lo), universe.to_list(hi)]
    )
    target_text = (
        universe.format(lo) if lo == hi else f"[{universe.format(lo)}, {universe.format(hi)}]"
    )
    if args.json:
        out: dict[str, Any] = {
            "polynomial": format_expr(poly, star),
            "subject": subject,
            "target": target_json,
            "mode": args.mode,
            "count": count,
        }
        if fixed:
            out["fixed"] = {s: universe.to_list(v) for s, v in fixed.items()}
        if not args.count_only:
            out["solutions"] = [{s: universe.to_list(v) for s, v in sol.items()} for sol in listed]
            out["truncated"] = truncated
        print(json.dumps(out))
        return 0

    form = canonical_forms(df)[subject]
    print(f"polynomial: {format_expr(poly, star)}    F = {df.text()}")
    print(f"controlled subject: {form.text(star)}")
    print(
        f"target: {target_text} (mode {args.mode})"
        + (
            ", fixed: " + ", ".join(f"{s}>{subject}={universe.format(v)}" for s, v in fixed.items())
            if fixed
            else ""
        )
    )
    print(f"solutions: {count}")
    for sol in listed:
        print("  " + "  ".join(f"{s}={universe.format(v)}" for s, v in sol.items()))
    if truncated:
        print(f"  ... {count - len(listed)} more (raise --limit, or --count-only)")
    return 0
