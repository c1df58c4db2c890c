"""Safe evaluation of curve expressions in the parameter s (no Python eval).

An expression such as ``(8 + sin(4*pi*s)) * cos(2*pi*s) + 4`` is parsed with :mod:`ast` and
accepted only if it uses numbers, the variable ``s``, the constants ``pi``, ``e``, ``tau``,
arithmetic (+ - * / ** and unary signs) and the functions in :data:`FUNCTIONS`. It is then
evaluated on a numpy array of s values.
"""

import ast
import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from curve_formation.core.base.shapes import FloatArray


FUNCTIONS = {
    'sin': np.sin, 'cos': np.cos, 'tan': np.tan,
    'asin': np.arcsin, 'acos': np.arccos, 'atan': np.arctan, 'atan2': np.arctan2,
    'sinh': np.sinh, 'cosh': np.cosh, 'tanh': np.tanh,
    'exp': np.exp, 'log': np.log, 'sqrt': np.sqrt, 'abs': np.abs,
    'min': np.minimum, 'max': np.maximum,
}
CONSTANTS = {'pi': math.pi, 'e': math.e, 'tau': math.tau}
VARIABLE = 's'

_BINARY = {
    ast.Add: np.add, ast.Sub: np.subtract, ast.Mult: np.multiply,
    ast.Div: np.divide, ast.Pow: np.power,
}
_UNARY = {ast.USub: np.negative, ast.UAdd: np.positive}


# An expression's text and syntax tree are bounded; within them it is checked and evaluated
# without recursion (a sum of a thousand terms is a tree a thousand deep).
MAX_LENGTH = 5000
MAX_NODES = 5000


class ExpressionError(ValueError):
    """An expression that does not parse or uses something beyond arithmetic and math."""


class Expression:
    """A validated scalar expression of s; call it with an array of s to evaluate."""

    def __init__(self, text: str) -> None:
        if not isinstance(text, str) or not text.strip():
            raise ExpressionError(f'expected a non-empty expression in s, got '
                                  f'{_short(repr(text))}')
        self.text = text
        self.label = _short(repr(text.strip()))
        if len(text) > MAX_LENGTH:
            raise ExpressionError(f'{self.label}: {len(text)} characters; at most '
                                  f'{MAX_LENGTH} expected')
        try:
            tree = ast.parse(text.strip(), mode='eval')
        except SyntaxError as exc:
            raise ExpressionError(f'cannot parse {self.label}: {exc.msg}') from None
        except ValueError as exc:   # e.g. a null byte: ast.parse refuses it outright
            raise ExpressionError(f'cannot parse {self.label}: {exc}') from None
        except (RecursionError, MemoryError):
            raise ExpressionError(f'{self.label}: nested too deeply to parse') from None
        self._order = self._checked(tree.body)

    def __call__(self, s: ArrayLike) -> FloatArray:
        """Evaluate on s (scalar or array); returns an array broadcast to s's shape."""
        s = np.asarray(s, dtype=float)
        values: dict[int, np.ndarray] = {}
        with np.errstate(all='ignore'):
            for node in self._order:   # children before parents
                values[id(node)] = self._value(node, s, values)
            value = np.broadcast_to(values[id(self._order[-1])], s.shape).astype(float)
        if not np.all(np.isfinite(value)):
            raise ExpressionError(f'{self.label} is not finite for some s in [0, 1]')
        return value

    def _checked(self, root: ast.AST) -> list[ast.AST]:
        """The tree's nodes, each after its children; ExpressionError for what is not
        allowed. Iterative (a stack), bounded by MAX_NODES.
        """
        order, stack = [], [(root, False)]
        while stack:
            node, expanded = stack.pop()
            if expanded:
                order.append(node)
                continue
            if len(order) + len(stack) > MAX_NODES:
                raise ExpressionError(f'{self.label}: more than {MAX_NODES} terms')
            self._check(node)
            stack.append((node, True))
            stack.extend((child, False) for child in reversed(_children(node)))
        return order

    def _check(self, node: ast.AST) -> None:
        if isinstance(node, ast.Constant):
            if isinstance(node.value, bool) or not isinstance(node.value, (int, float)):
                raise ExpressionError(f'{self.label}: only numbers are allowed as constants, '
                                      f'not {_short(repr(node.value))}')
            try:
                number = float(node.value)
            except OverflowError:
                number = math.inf
            if not math.isfinite(number):
                raise ExpressionError(f'{self.label}: the number {_short(str(node.value))} '
                                      'is too large')
        elif isinstance(node, ast.Name):
            if node.id != VARIABLE and node.id not in CONSTANTS:
                raise ExpressionError(
                    f'{self.label}: unknown name {_short(node.id)!r}; expected s or one of '
                    f'{sorted(CONSTANTS)}')
        elif isinstance(node, ast.BinOp):
            if type(node.op) not in _BINARY:
                raise ExpressionError(f'{self.label}: operator {type(node.op).__name__} '
                                      'is not allowed (use + - * / **)')
        elif isinstance(node, ast.UnaryOp):
            if type(node.op) not in _UNARY:
                raise ExpressionError(f'{self.label}: operator {type(node.op).__name__} '
                                      'is not allowed')
        elif isinstance(node, ast.Call):
            if not isinstance(node.func, ast.Name) or node.func.id not in FUNCTIONS:
                name = getattr(node.func, 'id', None) or type(node.func).__name__
                raise ExpressionError(f'{self.label}: function {_short(name)!r} is not '
                                      f'allowed; allowed: {sorted(FUNCTIONS)}')
            if node.keywords:
                raise ExpressionError(f'{self.label}: keyword arguments are not allowed')
        else:
            raise ExpressionError(f'{self.label}: {type(node).__name__} is not allowed '
                                  '(only arithmetic and math functions of s)')

    def _value(self, node: Any, s: Any, values: dict[int, Any]) -> Any:
        if isinstance(node, ast.Constant):
            return float(node.value)   # type: ignore[arg-type]  # _checked: numbers only
        if isinstance(node, ast.Name):
            return s if node.id == VARIABLE else CONSTANTS[node.id]
        if isinstance(node, ast.BinOp):
            return _BINARY[type(node.op)](values[id(node.left)], values[id(node.right)])
        if isinstance(node, ast.UnaryOp):
            return _UNARY[type(node.op)](values[id(node.operand)])
        args = [values[id(arg)] for arg in node.args]
        try:
            return FUNCTIONS[node.func.id](*args)
        except TypeError as exc:
            raise ExpressionError(f'{self.label}: {node.func.id}(): {exc}') from None


def _children(node: ast.AST) -> list[ast.AST]:
    """The sub-expressions of an allowed node, in evaluation order."""
    if isinstance(node, ast.BinOp):
        return [node.left, node.right]
    if isinstance(node, ast.UnaryOp):
        return [node.operand]
    if isinstance(node, ast.Call):
        return list(node.args)
    return []


def _short(text: str, limit: int = 60) -> str:
    return text if len(text) <= limit else text[:limit - 3] + '...'
