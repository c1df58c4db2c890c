import numpy as np
import pytest

from curve_formation.core.formation.expressions import Expression, ExpressionError


def test_evaluates_paper_curve_on_arrays():
    s = np.linspace(0, 1, 7)
    got = Expression('(8 + sin(4*pi*s)) * cos(2*pi*s) + 4')(s)
    np.testing.assert_allclose(got, (8 + np.sin(4 * np.pi * s)) * np.cos(2 * np.pi * s) + 4)


def test_constant_expression_broadcasts():
    assert Expression('2.5')(np.zeros(4)).shape == (4,)


@pytest.mark.parametrize('text, fragment', [
    ('__import__("os").system("true")', 'not allowed'),
    ('s.real', 'Attribute'),
    ('foo(s)', "function 'foo'"),
    ('t + 1', "unknown name 't'"),
    ('lambda: 1', 'Lambda'),
    ('sin(s', 'cannot parse'),
    ('s if s else 1', 'IfExp'),
    ('"a" * 3', 'only numbers'),
    ('s // 2', 'FloorDiv'),
    ('', 'non-empty'),
    ('log(s - 2)', 'not finite'),
])
def test_refuses_anything_beyond_arithmetic(text, fragment):
    with pytest.raises(ExpressionError, match=fragment.replace('(', r'\(')):
        Expression(text)(np.linspace(0, 1, 5))


def test_a_null_byte_is_refused_as_an_expression_error():
    """Found by the mutation property test: ast.parse raises ValueError, not SyntaxError."""
    with pytest.raises(ExpressionError, match='cannot parse'):
        Expression('sin(2*pi*s)\x00')
