import numpy as np
import pytest

from curve_formation.core.formation.graph import DirectedGraph, Edge, GraphError


def chain(n):
    return [Edge(i, i + 1) for i in range(1, n)]


def random_rooted_graph(rng, n, pinning=0.0):
    """A random spanning tree from agent 1 plus random extra edges (none into the leader)."""
    edges = {(int(rng.integers(1, i)), i): float(rng.uniform(0.2, 2)) for i in range(2, n + 1)}
    for _ in range(n):
        a, b = rng.integers(1, n + 1, size=2)
        if a != b and b != 1:
            edges.setdefault((int(a), int(b)), float(rng.uniform(0.2, 2)))
    return DirectedGraph(n, [Edge(a, b, w) for (a, b), w in edges.items()],
                         follower_pinning=pinning)


def test_laplacian_as_in_the_paper():
    g = DirectedGraph(3, [Edge(1, 2, 2.0), Edge(2, 3), Edge(1, 3, 0.5)])
    np.testing.assert_allclose(g.laplacian, [[0, 0, 0], [-2, 2, 0], [-0.5, -1, 1.5]])
    np.testing.assert_allclose(g.laplacian @ np.ones(3), 0)
    assert g.in_neighbours(3) == [(1, 0.5), (2, 1.0)]
    assert g.out_neighbours(1) == [2, 3]


@pytest.mark.parametrize('seed', range(20))
def test_certificate_positive_definite_on_random_rooted_graphs(seed):
    rng = np.random.default_rng(seed)
    # every other graph pins its followers too (b e_i added to their feedback)
    g = random_rooted_graph(rng, int(rng.integers(2, 30)), (seed % 2) * rng.uniform(0.1, 3))
    np.testing.assert_allclose(np.diag(g.feedback_matrix - g.laplacian), g.pins)
    cert = g.certificate()
    assert cert.min_eig_P > 0 and cert.min_eig_Q > 0
    m = g.feedback_matrix
    np.testing.assert_allclose(cert.Q, cert.P @ m + m.T @ cert.P)


@pytest.mark.parametrize('n, edges, fragment', [
    (4, [Edge(1, 2), Edge(3, 4)], 'receive from nobody'),
    (4, [Edge(1, 2), Edge(2, 3), Edge(3, 4), Edge(4, 1)], 'leader .* must receive from nobody'),
    (3, [Edge(1, 2), Edge(2, 3), Edge(3, 2), Edge(4, 3)], 'agents are numbered 1..3'),
    (3, [Edge(1, 2), Edge(2, 2)], 'self-loop'),
    (3, [Edge(1, 2), Edge(2, 3, -1.0)], 'weight'),
    (3, [Edge(1, 2), Edge(1, 2), Edge(2, 3)], 'twice'),
])
def test_refuses_unusable_graphs(n, edges, fragment):
    with pytest.raises(GraphError, match=fragment):
        DirectedGraph(n, edges)


@pytest.mark.parametrize('pinning', [-0.5, float('nan'), float('inf')])
def test_refuses_a_bad_follower_pinning(pinning):
    with pytest.raises(GraphError, match='pinning'):
        DirectedGraph(3, chain(3), follower_pinning=pinning)


def test_unreachable_cycle_is_refused_as_no_spanning_tree():
    # 3 and 4 feed each other but nothing from the leader reaches them.
    with pytest.raises(GraphError, match=r'no spanning tree .* agents \[3, 4\]'):
        DirectedGraph(4, [Edge(1, 2), Edge(3, 4), Edge(4, 3)])


def test_chain_is_accepted():
    assert DirectedGraph(5, chain(5)).reachable_from(1) == {1, 2, 3, 4, 5}


def test_hops_from_leader():
    g = DirectedGraph(5, [Edge(1, 2), Edge(2, 3), Edge(1, 3), Edge(3, 4), Edge(4, 5), Edge(5, 2)])
    assert g.hops_from_leader().tolist() == [0, 1, 1, 2, 3]
