"""Reflexive Game Theory engine: pure Python, no I/O.

graph -> polynomial -> stratification tree / diagonal form -> fold -> F -> canonical forms ->
forward task (intervals, frustration) and inverse task (reflexive control).
"""

from typing import TYPE_CHECKING, Any

from rgtbus.rgt.algebra import Universe
from rgtbus.rgt.decision import (
    CanonicalForm,
    InfluenceMatrix,
    SubjectResult,
    canonical_form,
    canonical_forms,
    evaluate,
    forward,
)
from rgtbus.rgt.diagonal import (
    DecisionFunction,
    decision_function,
    diagonal_inline,
    diagonal_text,
    fold,
    stratification_text,
)
from rgtbus.rgt.expr import Expr, format_expr
from rgtbus.rgt.polynomial import (
    RelationGraph,
    find_p4,
    graph_to_polynomial,
    install_relations,
    parse_polynomial,
    polynomial_to_graph,
    random_polynomial,
)

# The inverse task is imported when first used: a run without goals never steers, and every
# command's start-up would otherwise pay for importing it and ``fractions``.
_CONTROL = (
    "STEER_RULES",
    "ControlResult",
    "SteeringChoice",
    "meets",
    "solve_brute_force",
    "solve_per_action",
    "steer",
    "steerable_share",
)
if TYPE_CHECKING:
    from rgtbus.rgt.control import (
        STEER_RULES,
        ControlResult,
        SteeringChoice,
        meets,
        solve_brute_force,
        solve_per_action,
        steer,
        steerable_share,
    )


def __getattr__(name: str) -> Any:
    if name in _CONTROL:
        from rgtbus.rgt import control

        value = getattr(control, name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'rgtbus.rgt' has no attribute {name!r}")


__all__ = [
    "STEER_RULES",
    "CanonicalForm",
    "ControlResult",
    "DecisionFunction",
    "Expr",
    "InfluenceMatrix",
    "RelationGraph",
    "SteeringChoice",
    "SubjectResult",
    "Universe",
    "canonical_form",
    "canonical_forms",
    "decision_function",
    "diagonal_inline",
    "diagonal_text",
    "evaluate",
    "find_p4",
    "fold",
    "format_expr",
    "forward",
    "graph_to_polynomial",
    "install_relations",
    "meets",
    "parse_polynomial",
    "polynomial_to_graph",
    "random_polynomial",
    "solve_brute_force",
    "solve_per_action",
    "steer",
    "steerable_share",
    "stratification_text",
]
