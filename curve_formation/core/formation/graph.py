"""Directed communication graph, its Laplacian and the paper's Theorem 1 certificate.

Agents are numbered 1..n as in the paper and in the robots' namespaces; arrays are indexed
0..n-1. An edge (source -> target, weight a) means the target receives from the source:
a_{target, source} = a > 0. The leader receives from nobody and must reach every agent.
"""

from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from curve_formation.core.base.shapes import FloatArray, IntArray


class GraphError(ValueError):
    """A graph that the controller cannot use."""


@dataclass(frozen=True)
class Edge:
    """Agent `target` receives agent `source`'s state with weight `weight` (> 0)."""

    source: int
    target: int
    weight: float = 1.0


@dataclass(frozen=True)
class Certificate:
    """Theorem 1: q = (L+B)^-1 1, p = (L+B)^-T 1, P = diag(p/q), Q = P(L+B) + (L+B)^T P."""

    P: FloatArray  # noqa: N815 - the paper's names
    Q: FloatArray  # noqa: N815
    min_eig_P: float  # noqa: N815
    min_eig_Q: float  # noqa: N815


class DirectedGraph:
    """Weighted directed graph over agents 1..n with agent `leader` as root.

    follower_pinning b >= 0 weighs each follower's own target error in its feedback
    (b e_i + sum_j a_ij (e_i - e_j)); the paper has b = 0. Any b keeps Theorem 1: L + B
    stays a nonsingular M-matrix, and certificate() checks P and Q.
    """

    def __init__(self, n: int, edges: Iterable[Edge], leader: int = 1,
                 follower_pinning: float = 0.0) -> None:
        self.n = int(n)
        if self.n < 1:
            raise GraphError(f'a formation needs at least one agent, got n = {n}')
        self.leader = int(leader)
        self.follower_pinning = float(follower_pinning)
        if not (self.follower_pinning >= 0 and np.isfinite(self.follower_pinning)):
            raise GraphError(f'follower pinning must be finite and >= 0, got {follower_pinning}')
        self.edges = tuple(Edge(int(e.source), int(e.target), float(e.weight)) for e in edges)
        self.adjacency = np.zeros((self.n, self.n))
        for edge in self.edges:
            for end in (edge.source, edge.target):
                if not 1 <= end <= self.n:
                    raise GraphError(f'edge {edge.source} -> {edge.target} names agent {end}, '
                                     f'but agents are numbered 1..{self.n}')
            if edge.source == edge.target:
                raise GraphError(f'edge {edge.source} -> {edge.target} is a self-loop')
            if not (edge.weight > 0 and np.isfinite(edge.weight)):
                raise GraphError(f'edge {edge.source} -> {edge.target} has weight '
                                 f'{edge.weight}; weights must be finite and > 0')
            if self.adjacency[edge.target - 1, edge.source - 1]:
                raise GraphError(f'edge {edge.source} -> {edge.target} is given twice')
            self.adjacency[edge.target - 1, edge.source - 1] = edge.weight
        self._check_rooted()

    def _check_rooted(self) -> None:
        if not 1 <= self.leader <= self.n:
            raise GraphError(f'leader {self.leader} is not one of the agents 1..{self.n}')
        receives = [edge for edge in self.edges if edge.target == self.leader]
        if receives:
            raise GraphError(f'the leader (agent {self.leader}) must receive from nobody, but '
                             f'edge {receives[0].source} -> {self.leader} exists')
        roots = [i + 1 for i in range(self.n) if not self.adjacency[i].any()]
        if len(roots) > 1:
            raise GraphError(f'agents {roots} receive from nobody: only the leader '
                             f'(agent {self.leader}) may; every other agent needs an in-edge')
        unreached = sorted(set(range(1, self.n + 1)) - self.reachable_from(self.leader))
        if unreached:
            raise GraphError(f'the graph has no spanning tree rooted at the leader '
                             f'(agent {self.leader}): agents {unreached} cannot be reached')

    def reachable_from(self, root: int) -> set[int]:
        """Agents (1-based) that information from `root` reaches along the edges."""
        seen, queue = {root}, deque([root])
        while queue:
            source = queue.popleft()
            for target in np.flatnonzero(self.adjacency[:, source - 1]) + 1:
                if int(target) not in seen:
                    seen.add(int(target))
                    queue.append(int(target))
        return seen

    def hops_from_leader(self) -> IntArray:
        """(n,) number of edges on the shortest path from the leader to each agent."""
        hops = {self.leader: 0}
        queue = deque([self.leader])
        while queue:
            source = queue.popleft()
            for target in self.out_neighbours(source):
                if target not in hops:
                    hops[target] = hops[source] + 1
                    queue.append(target)
        return np.array([hops[i] for i in range(1, self.n + 1)])

    def in_neighbours(self, agent: int) -> list[tuple[int, float]]:
        """[(source, weight)] that agent (1-based) receives from, sorted by source."""
        row = self.adjacency[agent - 1]
        return [(int(j) + 1, float(row[j])) for j in np.flatnonzero(row)]

    def out_neighbours(self, agent: int) -> list[int]:
        """Agents (1-based) that receive from `agent`."""
        return [int(i) + 1 for i in np.flatnonzero(self.adjacency[:, agent - 1])]

    @property
    def laplacian(self) -> FloatArray:
        """L with l_ii = sum_j a_ij and l_ij = -a_ij: (n, n). The leader's row is zero."""
        return np.diag(self.adjacency.sum(axis=1)) - self.adjacency

    @property
    def pinning(self) -> FloatArray:
        """B = diag(1 for the leader, b for the followers): (n, n), the paper's Lambda."""
        return np.diag(self.pins)

    @property
    def pins(self) -> FloatArray:
        """diag(B): (n,), each agent's weight on its own target error."""
        b = np.full(self.n, self.follower_pinning)
        b[self.leader - 1] = 1.0
        return b

    @property
    def feedback_matrix(self) -> FloatArray:
        """L + B: the stacked feedback is (L + B) e for target errors e (n, 2)."""
        return self.laplacian + self.pinning

    def certificate(self) -> Certificate:
        """Theorem 1's P and Q, checked positive definite."""
        m = self.feedback_matrix
        q = np.linalg.solve(m, np.ones(self.n))
        p = np.linalg.solve(m.T, np.ones(self.n))
        if np.any(q <= 0) or np.any(p <= 0):
            raise GraphError('Theorem 1 does not apply: (L+B)^-1 1 or (L+B)^-T 1 has a '
                             'non-positive entry')
        big_p = np.diag(p / q)
        big_q = big_p @ m + m.T @ big_p
        cert = Certificate(big_p, big_q, float(np.linalg.eigvalsh(big_p).min()),
                           float(np.linalg.eigvalsh(big_q).min()))
        if cert.min_eig_P <= 0 or cert.min_eig_Q <= 0:
            raise GraphError(f'Theorem 1 certificate is not positive definite '
                             f'(min eig P = {cert.min_eig_P:.3g}, Q = {cert.min_eig_Q:.3g})')
        return cert

    def edge_arrays(self) -> tuple[IntArray, IntArray, FloatArray]:
        """(targets, sources, weights) as 0-based int arrays and a float array, for kernels."""
        targets = np.array([e.target - 1 for e in self.edges], dtype=np.int64)
        sources = np.array([e.source - 1 for e in self.edges], dtype=np.int64)
        weights = np.array([e.weight for e in self.edges], dtype=float)
        return targets, sources, weights
