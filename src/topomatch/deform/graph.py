"""Deformation graphs: a coarse set of nodes that carries a dense mesh's deformation.

Nodes are farthest-point samples of the vertices; each vertex belongs to the node
nearest along the mesh's edge graph (a geodesic Voronoi cell), two nodes are linked
when their cells share an edge, and each vertex is skinned to its own node and that
node's neighbours with Gaussian weights. Because cells grow along the surface, parts
that touch in space but not on the surface (a hand held against the hip) do not share
nodes or links.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph

from topomatch.mesh.geometry import edge_graph, unique_index_pairs
from topomatch.mesh.sampling import farthest_point_sampling
from topomatch.typing import FloatArray, IndexArray

__all__ = ["DeformationGraph", "build_deformation_graph"]


@dataclass(frozen=True, eq=False)
class DeformationGraph:
    """Nodes, links and skinning weights of a deformation graph.

    Attributes
    ----------
    nodes : ndarray, shape (m,)
        Vertex index of each node.
    rest : ndarray, shape (m, 3)
        Rest positions of the nodes.
    links : ndarray, shape (n_links, 2)
        Undirected node pairs, ``links[:, 0] < links[:, 1]``.
    link_weights : ndarray, shape (n_links,)
        Number of mesh edges between the two cells, normalised to mean 1.
    labels : ndarray, shape (n_vertices,)
        Node whose cell holds each vertex.
    skin : scipy.sparse.csr_matrix, shape (n_vertices, m)
        Skinning weights; rows sum to one.
    spacing : float
        Mean link length at rest.
    """

    nodes: IndexArray
    rest: FloatArray
    links: IndexArray
    link_weights: FloatArray
    labels: IndexArray
    skin: sparse.csr_matrix
    spacing: float

    @property
    def n_nodes(self) -> int:
        """Number of nodes."""
        return len(self.nodes)


def build_deformation_graph(
    vertices: FloatArray,
    faces: IndexArray,
    n_nodes: int,
    *,
    skin_radius: float = 1.0,
    random_state: int | np.random.Generator | None = None,
    first: int | None = None,
) -> DeformationGraph:
    """Sample nodes on a mesh and build links and skinning weights.

    Parameters
    ----------
    vertices : ndarray, shape (n, 3)
    faces : ndarray, shape (n_faces, 3)
    n_nodes : int
        Number of nodes, at most the number of vertices.
    skin_radius : float
        Gaussian width of the skinning weights in units of the mean link length.
    random_state : int, Generator or None
        First farthest-point sample (drawn among the vertices that faces use).
    first : int, optional
        First farthest-point sample as a vertex index: that vertex, or when no face
        uses it the next vertex that one does (the last such vertex if none follows).
        Default: the first vertex a face uses (or ``random_state``'s draw).

    Returns
    -------
    DeformationGraph
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    n = len(v)
    if not 1 <= n_nodes <= n:
        raise ValueError(f"n_nodes must lie in [1, {n}], got {n_nodes}")
    used = np.zeros(n, dtype=bool)
    used[f.ravel()] = True
    cand = np.flatnonzero(used)
    start = 0
    if first is not None:
        if not isinstance(first, (int, np.integer)) or not 0 <= first < n:
            raise ValueError(f"first must be a vertex index in [0, {n}), got {first!r}")
        start = min(int(np.searchsorted(cand, first)), len(cand) - 1)
    elif random_state is not None:
        from topomatch._validation import check_random_state

        start = int(check_random_state(random_state).integers(len(cand)))
    nodes = cand[farthest_point_sampling(min(n_nodes, len(cand)), points=v[cand], first=start)]
    g = edge_graph(v, f)
    dist, _, src = csgraph.dijkstra(g, directed=False, indices=nodes, min_only=True, return_predecessors=True)
    node_of_vertex = np.full(n, -1, dtype=np.int64)
    node_index = np.full(n, -1, dtype=np.int64)
    node_index[nodes] = np.arange(len(nodes))
    reach = src >= 0
    node_of_vertex[reach] = node_index[src[reach]]
    if np.any(~reach):  # vertices in components without a node: nearest node in space
        miss = np.flatnonzero(~reach)
        d2 = ((v[miss, None, :] - v[nodes][None, :, :]) ** 2).sum(-1)
        node_of_vertex[miss] = np.argmin(d2, axis=1)
    # links between cells that share a mesh edge
    gi, gj = g.nonzero()
    a, b = node_of_vertex[gi], node_of_vertex[gj]
    cross = a < b
    m = len(nodes)
    pairs, counts = unique_index_pairs(a[cross], b[cross], m)  # shapes (0, 2) and (0,) when there are none
    weights = counts / counts.mean() if len(counts) else counts.astype(np.float64)
    rest = v[nodes]
    spacing = float(np.linalg.norm(rest[pairs[:, 0]] - rest[pairs[:, 1]], axis=1).mean()) if len(pairs) else 1.0
    # skinning: own node plus its linked nodes, Gaussian in Euclidean distance
    adj = sparse.csr_matrix((np.ones(2 * len(pairs)), (np.r_[pairs[:, 0], pairs[:, 1]], np.r_[pairs[:, 1], pairs[:, 0]])), shape=(m, m))
    adj = (adj + sparse.identity(m, format="csr")).tocsr()
    own = sparse.csr_matrix((np.ones(n), (np.arange(n), node_of_vertex)), shape=(n, m))
    cand_mat = (own @ adj).tocsr()
    rows = np.repeat(np.arange(n), np.diff(cand_mat.indptr))
    cols = cand_mat.indices
    d2 = ((v[rows] - rest[cols]) ** 2).sum(1)
    sigma = skin_radius * spacing
    w = np.exp(-d2 / (2 * sigma**2))
    skin = sparse.csr_matrix((w, (rows, cols)), shape=(n, m))
    tot = np.asarray(skin.sum(axis=1)).ravel()
    bad = tot <= 1e-12
    if np.any(bad):  # far from every candidate: hard-assign to the own node
        skin = skin.tolil()
        for i in np.flatnonzero(bad):
            skin[i, :] = 0
            skin[i, node_of_vertex[i]] = 1.0
        skin = skin.tocsr()
        tot = np.asarray(skin.sum(axis=1)).ravel()
    skin = (sparse.diags(1.0 / tot) @ skin).tocsr()
    skin.sort_indices()  # canonical order, so users never need to sort (and mutate) a shared graph
    del dist
    return DeformationGraph(
        nodes=nodes,
        rest=rest,
        links=pairs.astype(np.int64),
        link_weights=np.asarray(weights, dtype=np.float64),
        labels=node_of_vertex,
        skin=skin,
        spacing=spacing,
    )
