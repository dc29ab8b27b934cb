"""Small arithmetic expressions over metric and parameter names, parsed with a whitelist.

A spec's objective, measures and failure condition are written as text such as
``100 - completion_time`` or ``norm(noise)`` or ``objective >= 60``. They come from files
that may be shared, so they are never passed to ``eval``: the text is parsed with
:mod:`ast`, every node is checked against a whitelist, and the tree is evaluated by a
tiny interpreter. Only numbers, names, ``+ - * /``, unary minus, integer indexing,
comparisons, ``and``/``or``/``not`` and the functions in :data:`FUNCTIONS` exist.
"""

from __future__ import annotations

import ast
import math
import operator
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np


def _norm(*args: object) -> float:
    return float(np.linalg.norm(np.concatenate([np.ravel(np.asarray(a, dtype=float)) for a in args])))


def _reduce(fn: Callable[..., float]) -> Callable[..., float]:
    def apply(*args: object) -> float:
        flat = np.concatenate([np.ravel(np.asarray(a, dtype=float)) for a in args])
        return float(fn(flat))

    return apply


FUNCTIONS: dict[str, Callable[..., float]] = {
    "abs": lambda x: np.abs(x) if np.ndim(x) else abs(float(x)),
    "sqrt": lambda x: np.sqrt(x) if np.ndim(x) else math.sqrt(float(x)),
    "min": _reduce(np.min),
    "max": _reduce(np.max),
    "norm": _norm,
}

_BINARY = {ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul, ast.Div: operator.truediv}
_UNARY = {ast.USub: operator.neg, ast.UAdd: operator.pos, ast.Not: operator.not_}
_COMPARE = {
    ast.Lt: operator.lt,
    ast.LtE: operator.le,
    ast.Gt: operator.gt,
    ast.GtE: operator.ge,
    ast.Eq: operator.eq,
    ast.NotEq: operator.ne,
}


# An expression is a line of arithmetic; the cap keeps parsing, checking and every message that
# quotes one small, whatever a shared spec holds.
MAX_LENGTH = 500


class ExpressionError(ValueError):
    """An expression that does not parse or uses something outside the whitelist."""


@dataclass(frozen=True)
class Expression:
    """A parsed, whitelisted expression. Build with :func:`parse`."""

    text: str
    tree: ast.expr = field(repr=False, compare=False)
    names: frozenset[str] = field(compare=False)
    is_condition: bool = field(compare=False)

    def evaluate(self, env: Mapping[str, object]) -> float | bool:
        """Evaluates with ``env`` mapping each name to a number or an array."""
        return _evaluate(self.tree, env)

    def clauses(self) -> tuple[Expression, ...]:
        """The operands of a top-level ``or`` / ``and``, each as an expression of its own; else itself.

        A failure condition ``objective >= 15 or approach >= 0.3`` has two clauses: reports say which
        of them held, so a safety failure is told apart from a slow one.
        """
        if not isinstance(self.tree, ast.BoolOp):
            return (self,)
        return tuple(
            Expression(
                text=ast.unparse(child),
                tree=child,
                names=frozenset(n.id for n in ast.walk(child) if isinstance(n, ast.Name) and n.id not in FUNCTIONS),
                is_condition=True,
            )
            for child in self.tree.values
        )


def parse(text: str, *, condition: bool = False) -> Expression:
    """Parses ``text``; ``condition=True`` requires a comparison (a failure condition).

    Raises:
        ExpressionError: with a message that says what construct is not allowed.
    """
    if not isinstance(text, str) or not text.strip():
        raise ExpressionError("expected an expression such as 'completion_time' or 'norm(noise)'")
    if len(text) > MAX_LENGTH:
        raise ExpressionError(
            f"is {len(text)} characters long; an expression has at most {MAX_LENGTH}: compute the rest in the "
            "task plugin and report it as a metric"
        )
    try:
        tree = ast.parse(text.strip(), mode="eval").body
    except SyntaxError as exc:
        raise ExpressionError(f"{text!r} is not a valid expression: {exc.msg}") from None
    names: set[str] = set()
    _check(tree, names)
    _check_constants(tree)
    is_condition = isinstance(tree, ast.Compare | ast.BoolOp) or (
        isinstance(tree, ast.UnaryOp) and isinstance(tree.op, ast.Not)
    )
    if condition and not is_condition:
        raise ExpressionError(f"{text!r} is not a condition: write a comparison such as 'objective >= 60'")
    if not condition and is_condition:
        raise ExpressionError(f"{text!r} is a condition; a numeric expression is expected here")
    return Expression(text=text.strip(), tree=tree, names=frozenset(names), is_condition=is_condition)


def _check(node: ast.AST, names: set[str]) -> None:
    if isinstance(node, ast.Constant):
        if isinstance(node.value, bool) or not isinstance(node.value, int | float):
            raise ExpressionError(f"only numbers are allowed as constants, not {node.value!r}")
    elif isinstance(node, ast.Name):
        if node.id.startswith("_"):
            raise ExpressionError(f"names starting with '_' are not allowed: {node.id!r}")
        if node.id not in FUNCTIONS:
            names.add(node.id)
        else:
            raise ExpressionError(f"{node.id!r} is a function: call it, e.g. {node.id}(x)")
    elif isinstance(node, ast.BinOp) and type(node.op) in _BINARY:
        _check(node.left, names)
        _check(node.right, names)
    elif isinstance(node, ast.UnaryOp) and type(node.op) in _UNARY:
        _check(node.operand, names)
    elif isinstance(node, ast.Compare) and all(type(op) in _COMPARE for op in node.ops):
        for child in (node.left, *node.comparators):
            _check(child, names)
    elif isinstance(node, ast.BoolOp):
        for child in node.values:
            _check(child, names)
    elif isinstance(node, ast.Call):
        if not isinstance(node.func, ast.Name) or node.func.id not in FUNCTIONS:
            what = ast.unparse(node.func)
            raise ExpressionError(f"calling {what!r} is not allowed; the functions are {', '.join(FUNCTIONS)}")
        if node.keywords or not node.args:
            raise ExpressionError(f"{node.func.id}() takes one or more positional arguments")
        for arg in node.args:
            _check(arg, names)
    elif isinstance(node, ast.Subscript):
        if not isinstance(node.value, ast.Name):
            raise ExpressionError("only a parameter group may be indexed, as in noise[0]")
        index = node.slice
        if not (isinstance(index, ast.Constant) and type(index.value) is int):
            raise ExpressionError("an index must be a whole number, as in noise[0]")
        _check(node.value, names)
    elif isinstance(node, ast.Attribute):
        raise ExpressionError(f"attribute access is not allowed: {ast.unparse(node)!r}")
    else:
        raise ExpressionError(f"{ast.unparse(node)!r} is not allowed ({type(node).__name__})")


def _check_constants(tree: ast.expr) -> None:
    """Computes every part of ``tree`` that holds no name, so that ``x / 0`` fails here and not in each run."""
    for node in ast.walk(tree):
        if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Div) and _constant(node.right):
            _check_constants(node.right)
            if _evaluate(node.right, {}) == 0:
                raise ExpressionError(f"{ast.unparse(node)!r} divides by zero; change the divisor")
        if not isinstance(node, ast.expr) or isinstance(node, ast.Name) or not _constant(node):
            continue
        try:
            with np.errstate(all="raise"):
                value = _evaluate(node, {})
        except (ArithmeticError, ValueError, TypeError, FloatingPointError) as exc:
            raise ExpressionError(
                f"{ast.unparse(node)!r} cannot be computed ({exc or type(exc).__name__}); change that constant part"
            ) from None
        if not np.all(np.isfinite(value)):
            raise ExpressionError(f"{ast.unparse(node)!r} is not a finite number; change that constant part")


def _constant(node: ast.expr) -> bool:
    """Whether ``node`` holds no name but the functions it calls."""
    return not any(isinstance(n, ast.Name) and n.id not in FUNCTIONS for n in ast.walk(node))


def _evaluate(node: ast.expr, env: Mapping[str, object]):  # noqa: ANN202 - numbers or arrays
    if isinstance(node, ast.Constant):
        return node.value
    if isinstance(node, ast.Name):
        return env[node.id]
    if isinstance(node, ast.BinOp):
        return _BINARY[type(node.op)](_evaluate(node.left, env), _evaluate(node.right, env))
    if isinstance(node, ast.UnaryOp):
        return _UNARY[type(node.op)](_evaluate(node.operand, env))
    if isinstance(node, ast.Compare):
        left = _evaluate(node.left, env)
        for op, comparator in zip(node.ops, node.comparators):
            right = _evaluate(comparator, env)
            if not _COMPARE[type(op)](left, right):
                return False
            left = right
        return True
    if isinstance(node, ast.BoolOp):
        values = (_evaluate(child, env) for child in node.values)
        return all(values) if isinstance(node.op, ast.And) else any(values)
    if isinstance(node, ast.Call):
        return FUNCTIONS[node.func.id](*(_evaluate(arg, env) for arg in node.args))
    if isinstance(node, ast.Subscript):
        return np.asarray(env[node.value.id])[node.slice.value]
    raise AssertionError(f"unchecked node {type(node).__name__}")  # parse() rejects everything else
