"""Safe evaluation of curve expressions in the parameter s (no Python eval).

An expression such as ``(8 + sin(4*pi*s)) * cos(2*pi*s) + 4`` is parsed with :mod:`ast` and
accepted only if it uses numbers, the variable ``s``, the constants ``pi``, ``e``, ``tau``,
arithmetic (+ - * / ** and unary signs) and the functions in :data:`FUNCTIONS`. It is then
evaluated on a numpy array of s values.
"""

import ast
import math

import numpy as np


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


class ExpressionError(ValueError):
    """An expression that does not parse or uses something beyond arithmetic and math."""


class Expression:
    """A validated scalar expression of s; call it with an array of s to evaluate."""

    def __init__(self, text):
        if not isinstance(text, str) or not text.strip():
            raise ExpressionError(f'expected a non-empty expression in s, got {text!r}')
        self.text = text
        try:
            tree = ast.parse(text.strip(), mode='eval')
        except SyntaxError as exc:
            raise ExpressionError(f'cannot parse {text!r}: {exc.msg}') from None
        self._check(tree.body)
        self._tree = tree.body

    def __call__(self, s):
        """Evaluate on s (scalar or array); returns an array broadcast to s's shape."""
        s = np.asarray(s, dtype=float)
        with np.errstate(all='ignore'):
            value = np.broadcast_to(self._eval(self._tree, s), s.shape).astype(float)
        if not np.all(np.isfinite(value)):
            raise ExpressionError(f'{self.text!r} is not finite for some s in [0, 1]')
        return value

    def _check(self, node):
        if isinstance(node, ast.Constant):
            if isinstance(node.value, bool) or not isinstance(node.value, (int, float)):
                raise ExpressionError(f'{self.text!r}: only numbers are allowed as constants, '
                                      f'not {node.value!r}')
        elif isinstance(node, ast.Name):
            if node.id != VARIABLE and node.id not in CONSTANTS:
                raise ExpressionError(
                    f'{self.text!r}: unknown name {node.id!r}; expected s or one of '
                    f'{sorted(CONSTANTS)}')
        elif isinstance(node, ast.BinOp):
            if type(node.op) not in _BINARY:
                raise ExpressionError(f'{self.text!r}: operator {type(node.op).__name__} '
                                      'is not allowed (use + - * / **)')
            self._check(node.left)
            self._check(node.right)
        elif isinstance(node, ast.UnaryOp):
            if type(node.op) not in _UNARY:
                raise ExpressionError(f'{self.text!r}: operator {type(node.op).__name__} '
                                      'is not allowed')
            self._check(node.operand)
        elif isinstance(node, ast.Call):
            if not isinstance(node.func, ast.Name) or node.func.id not in FUNCTIONS:
                name = getattr(node.func, 'id', ast.unparse(node.func))
                raise ExpressionError(f'{self.text!r}: function {name!r} is not allowed; '
                                      f'allowed: {sorted(FUNCTIONS)}')
            if node.keywords:
                raise ExpressionError(f'{self.text!r}: keyword arguments are not allowed')
            for arg in node.args:
                self._check(arg)
        else:
            raise ExpressionError(f'{self.text!r}: {type(node).__name__} is not allowed '
                                  '(only arithmetic and math functions of s)')

    def _eval(self, node, s):
        if isinstance(node, ast.Constant):
            return float(node.value)
        if isinstance(node, ast.Name):
            return s if node.id == VARIABLE else CONSTANTS[node.id]
        if isinstance(node, ast.BinOp):
            return _BINARY[type(node.op)](self._eval(node.left, s), self._eval(node.right, s))
        if isinstance(node, ast.UnaryOp):
            return _UNARY[type(node.op)](self._eval(node.operand, s))
        args = [self._eval(arg, s) for arg in node.args]
        try:
            return FUNCTIONS[node.func.id](*args)
        except TypeError as exc:
            raise ExpressionError(f'{self.text!r}: {node.func.id}(): {exc}') from None
