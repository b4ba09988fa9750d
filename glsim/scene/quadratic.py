"""Quadratic surface elements as 9-node biquadratic patches (Q9), numpy float64.

Every quadratic face (Q8 serendipity, Q9 Lagrange, T6 triangle; the outer faces of hex20,
hex27, tet10 and wedge15 solids) is held as one Q9 patch with nodes in this order:

    0..3 the corners as in :mod:`glsim.scene.bilinear`: (ξ, η) = (−1,−1), (1,−1), (1,1), (−1,1)
    4..7 the mid-sides (0,−1), (1,0), (0,1), (−1,0)   (edges 0–1, 1–2, 2–3, 3–0)
    8    the centre (0, 0)

with the tensor-product shape functions Nᵢ(ξ, η) = L_a(ξ)·L_b(η), L₋(t) = t(t−1)/2,
L₀(t) = 1 − t², L₊(t) = t(t+1)/2. This is exact for each source element:

- Q9: its own nodes.
- Q8: the serendipity space lies inside the Q9 space, so the Q8 element *is* the Q9 patch
  whose centre is the Q8 map at (0, 0): x₈ = −¼ Σ corners + ½ Σ mid-sides.
- T6 (a, b, c; mid-sides ab, bc, ca): stored like a linear triangle, as the collapsed
  (Duffy) patch (a, b, c, c) with barycentrics λa = (1−ξ)(1−η)/4, λb = (1+ξ)(1−η)/4,
  λc = (1+η)/2. Those are bilinear in (ξ, η), so every quadratic polynomial in λ (the T6
  map) is biquadratic, and the Q9 patch through the T6 map at the 9 nodes reproduces it
  exactly: nodes (a, b, c, c, ab, bc, c, ca) and centre x₈ = −⅛a − ⅛b + ¼ab + ½bc + ½ca
  (the T6 map at λ = (¼, ¼, ½)). Truth reports this (ξ, η) for T6, as it does for T3.

Displacements are interpolated with the same shape functions (isoparametric), so the centre
of a Q8/T6 patch moves with the same weights of the nodal displacements.

A patch's connectivity is a row of 9 node indices; the centre entry is the node itself (Q9)
or one of the codes CENTRE_Q8 / CENTRE_T6 (derived as above).
"""
from __future__ import annotations

import numpy as np

from glsim.limits import keep

CENTRE_Q8 = -1
CENTRE_T6 = -2
NODE_XI = np.array([-1.0, 1.0, 1.0, -1.0, 0.0, 1.0, 0.0, -1.0, 0.0])
NODE_ETA = np.array([-1.0, -1.0, 1.0, 1.0, -1.0, 0.0, 1.0, 0.0, 0.0])
MIDSIDE_OF_EDGE = (4, 5, 6, 7)   # edge k = (corner k, corner k+1) has mid-side node 4 + k
REVERSED = np.array([1, 0, 3, 2, 4, 7, 6, 5, 8])   # ξ → −ξ: the mirrored patch (outward faces)
# a derived centre's weights over nodes 0..7 (x₈ = Σ wₖ xₖ), per centre code
CENTRE_WEIGHTS = ((CENTRE_Q8, np.array([-0.25, -0.25, -0.25, -0.25, 0.5, 0.5, 0.5, 0.5])),
                  (CENTRE_T6, np.array([-0.125, -0.125, 0.0, 0.0, 0.25, 0.5, 0.0, 0.5])))

NEWTON_TOL = 1e-13        # stop once max(|Δξ|, |Δη|) ≤ this
NEWTON_MAX_ITER = 30
RESIDUAL_REL = 1e-9       # …or, after NEWTON_MAX_ITER, accept a residual ≤ this × the element's size
INSIDE_TOL = 1e-9         # |ξ|, |η| ≤ 1 + this counts as inside
START_RANGE = 1.25        # a 2×2 sub-quad root farther out than this (sub-quad coordinates) is no start


def _lagrange(t):
    return np.stack([0.5 * t * (t - 1), 1 - t * t, 0.5 * t * (t + 1)], -1)


def _dlagrange(t):
    return np.stack([t - 0.5, -2 * t, t + 0.5], -1)


_IA = np.array([0, 2, 2, 0, 1, 2, 1, 0, 1])   # index of L(ξ) per node: 0 = L₋, 1 = L₀, 2 = L₊
_IB = np.array([0, 0, 2, 2, 0, 1, 2, 1, 1])


def shape_functions(xi, eta):
    """Q9 shape functions (..., 9) in the node order of the module docstring."""
    xi, eta = np.broadcast_arrays(np.asarray(xi, dtype=np.float64), np.asarray(eta, dtype=np.float64))
    return _lagrange(xi)[..., _IA] * _lagrange(eta)[..., _IB]


def shape_derivatives(xi, eta):
    """(∂N/∂ξ, ∂N/∂η), each (..., 9)."""
    xi, eta = np.broadcast_arrays(np.asarray(xi, dtype=np.float64), np.asarray(eta, dtype=np.float64))
    la, lb = _lagrange(xi)[..., _IA], _lagrange(eta)[..., _IB]
    return _dlagrange(xi)[..., _IA] * lb, la * _dlagrange(eta)[..., _IB]


def evaluate(P, xi, eta):
    """Forward map of patches P (..., 9, D) at (ξ, η) → (..., D)."""
    return np.einsum("...i,...id->...d", shape_functions(xi, eta), np.asarray(P, dtype=np.float64))


def patch_points(patches: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Control points (M, 9, D) of the patches (M, 9) from the per-node values X (N, D)
    (positions or displacements), the derived centres included."""
    patches = np.asarray(patches)
    P = X[np.maximum(patches, 0)]
    centre = patches[:, 8]
    for code, w in CENTRE_WEIGHTS:
        rows = np.flatnonzero(centre == code)
        if rows.size:
            P[rows, 8] = np.einsum("k,mkd->md", w, P[rows, :8])
    return P


def fold_centres(rows: np.ndarray, c: np.ndarray):
    """Per-control-point values c (n, 9, ...) of patches ``rows`` (n, 9) — derivatives, or the
    weights of a linear map — as per-node ones: the node columns (n, 9) and the values with a
    derived centre's (Q8, T6: CENTRE_WEIGHTS) spread over the 8 nodes and its own zeroed."""
    nodes, c = np.array(rows), np.array(c, dtype=np.float64)
    for code, w in CENTRE_WEIGHTS:
        k = np.flatnonzero(rows[:, 8] == code)
        c[k, :8] += w.reshape((1, 8) + (1,) * (c.ndim - 2)) * c[k, 8:9]
        c[k, 8] = 0.0
        nodes[k, 8] = rows[k, 0]
    return nodes, c


def element_points(quads: np.ndarray, patches, e: np.ndarray, X: np.ndarray) -> np.ndarray:
    """The elements ``e``'s corners (n, 4, D), or with ``patches`` (a quadratic mesh's) their 9
    control points (:func:`patch_points`), from the per-node values X (N, D)."""
    return X[quads[e]] if patches is None else patch_points(patches[e], X)


LEBESGUE = 1.5625   # max over the patch of Σ|Nᵢ(ξ, η)|: (max Σ|L(t)| = 1.25, at t = ±½)²


def surface_box(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """An axis-aligned box (lo, hi), each (..., D), that holds the whole surface of the patches
    P (..., 9, D): X − c = Σ Nᵢ (Pᵢ − c) as Σ Nᵢ = 1, so each coordinate of X lies within
    LEBESGUE × the control points' half-extent of their box's centre c (the shape functions
    take negative values: the surface can leave the control points' box)."""
    lo, hi = P.min(axis=-2), P.max(axis=-2)
    c, half = 0.5 * (lo + hi), 0.5 * LEBESGUE * (hi - lo)
    return c - half, c + half


def to_parent(i, j, n: int, xi_s, eta_s):
    """(ξ, η) of the parent patch from the local (ξs, ηs) of its sub-quad (i, j) of n × n."""
    return -1 + (2 * np.asarray(i) + 1 + xi_s) / n, -1 + (2 * np.asarray(j) + 1 + eta_s) / n


def piece_of(e, xi, eta, n: int):
    """The linear piece (of n × n per patch, :func:`linearize`'s order) holding patch e's
    (ξ, η), and the piece's own (ξs, ηs) (the inverse of :func:`to_parent`)."""
    ci = np.clip(np.floor((xi + 1) * n / 2), 0, n - 1)
    cj = np.clip(np.floor((eta + 1) * n / 2), 0, n - 1)
    return (e * n * n + cj * n + ci).astype(np.int64), (xi + 1) * n - 2 * ci - 1, (eta + 1) * n - 2 * cj - 1


def sub_quads(P: np.ndarray, n: int = 2) -> np.ndarray:
    """The n × n bilinear sub-quads (..., n·n, 4, D) through the patch evaluated on the n+1
    grid; piece k = j·n + i spans ξ ∈ [−1 + 2i/n, −1 + 2(i+1)/n], η likewise with j."""
    t = np.linspace(-1, 1, n + 1)
    xi, eta = np.meshgrid(t, t)                                  # [j, i]
    G = np.einsum("jik,...kd->...jid", shape_functions(xi, eta), P)
    return np.stack([G[..., :-1, :-1, :], G[..., :-1, 1:, :], G[..., 1:, 1:, :], G[..., 1:, :-1, :]],
                    -2).reshape(P.shape[:-2] + (n * n, 4, P.shape[-1]))


def newton(P2, q, xi, eta, scale):
    """Newton on the 2-D problem Σ Nᵢ(ξ, η)·P2ᵢ = q (P2 (K, 9, 2), q (K, 2)) from (ξ, η).

    Stopping rule: max(|Δξ|, |Δη|) ≤ NEWTON_TOL, or NEWTON_MAX_ITER iterations (steps clipped
    to ±1). Returns (ξ, η, ok): ok where the step rule stopped it, or after the last
    iteration the residual is ≤ RESIDUAL_REL × ``scale`` (K,) (a collapsed T6 corner, where
    det J = 0, converges only linearly); never NaN (a singular Jacobian stops the sample)."""
    xi, eta = np.array(xi, dtype=np.float64), np.array(eta, dtype=np.float64)
    o = P2[:, 8:9, :]
    P2, q = P2 - o, q - o[:, 0, :]
    active = np.ones(len(xi), bool)
    ok = np.zeros(len(xi), bool)
    for _ in range(NEWTON_MAX_ITER):
        a = np.flatnonzero(active)
        if not a.size:
            break
        dN_xi, dN_eta = shape_derivatives(xi[a], eta[a])
        f = np.einsum("ki,kid->kd", shape_functions(xi[a], eta[a]), P2[a]) - q[a]
        ja = np.einsum("ki,kid->kd", dN_xi, P2[a])
        jb = np.einsum("ki,kid->kd", dN_eta, P2[a])
        det = ja[:, 0] * jb[:, 1] - ja[:, 1] * jb[:, 0]
        good = (det != 0) & np.isfinite(det)
        safe = np.where(good, det, 1.0)
        dxi = np.clip(-(jb[:, 1] * f[:, 0] - jb[:, 0] * f[:, 1]) / safe, -1, 1)
        deta = np.clip(-(ja[:, 0] * f[:, 1] - ja[:, 1] * f[:, 0]) / safe, -1, 1)
        xi[a] = np.where(good, xi[a] + dxi, xi[a])
        eta[a] = np.where(good, eta[a] + deta, eta[a])
        done = good & (np.maximum(np.abs(dxi), np.abs(deta)) <= NEWTON_TOL)
        ok[a[done]] = True
        active[a[done | ~good]] = False
    rest = np.flatnonzero(~ok)
    if rest.size:
        f = np.einsum("ki,kid->kd", shape_functions(xi[rest], eta[rest]), P2[rest]) - q[rest]
        ok[rest] = np.linalg.norm(f, axis=1) <= RESIDUAL_REL * scale[rest]
    ok &= np.isfinite(xi) & np.isfinite(eta)
    return np.where(ok, xi, 0.0), np.where(ok, eta, 0.0), ok


def patch_size(P: np.ndarray) -> np.ndarray:
    """A length scale (…,) of each patch: its control points' largest extent."""
    return np.ptp(P, axis=-2).max(axis=-1)


def starts(p2_sub: np.ndarray, q: np.ndarray, n: int = 2):
    """Newton starts from the n × n sub-quads: for each sub-quad the two roots of its inverse
    bilinear map (:func:`glsim.scene.bilinear.invert_closed`) where they are usable (real,
    within START_RANGE of the sub-quad), and always its centre: a ray grazing a convex patch
    can meet it while missing the chord sub-quads (the roots are complex), and beside a
    silhouette inside a curved patch, where the ray meets it twice, the chords can be crossed
    near the farther root only (tests/test_quadratic.py's trough). As the parent's (ξ, η).
    p2_sub (K, n·n, 4, 2), q (K, 2) → xi, eta, ok of shape (n·n·3, K)."""
    from glsim.scene.bilinear import invert_closed

    K = len(q)
    xs, es, oks = [], [], []
    for k in range(n * n):
        x, e, ok = invert_closed(p2_sub[:, k], q)
        ok = ok & (np.abs(x) <= START_RANGE) & (np.abs(e) <= START_RANGE)
        x, e, ok = np.concatenate([x, np.zeros((1, K))]), np.concatenate([e, np.zeros((1, K))]), \
            np.concatenate([ok, np.ones((1, K), bool)])
        px, pe = to_parent(k % n, k // n, n, x, e)
        xs.append(px)
        es.append(pe)
        oks.append(ok)
    return (np.concatenate(xs).reshape(-1, K), np.concatenate(es).reshape(-1, K),
            np.concatenate(oks).reshape(-1, K))


def invert(P2: np.ndarray, q: np.ndarray, depth=None, n: int = 2):
    """All usable roots of Σ Nᵢ(ξ, η)·P2ᵢ = q inside the patch, from the n × n sub-quad starts,
    reduced to one per sample: the one of least ``depth(idx, ξ, η)`` (K-vector function) if
    given, else the first. P2 (K, 9, 2), q (K, 2). Returns (ξ, η, ok)."""
    K = len(q)
    sx, se, sok = starts(sub_quads(P2, n), q, n)
    scale = patch_size(P2)
    best_xi, best_eta = np.zeros(K), np.zeros(K)
    best_d = np.full(K, np.inf)
    found = np.zeros(K, bool)
    for r in range(len(sx)):
        idx = np.flatnonzero(sok[r])
        if not idx.size:
            continue
        xi, eta, ok = newton(P2[idx], q[idx], sx[r, idx], se[r, idx], scale[idx])
        ok &= (np.abs(xi) <= 1 + INSIDE_TOL) & (np.abs(eta) <= 1 + INSIDE_TOL)
        idx, xi, eta = idx[ok], xi[ok], eta[ok]
        d = depth(idx, xi, eta) if depth is not None else np.zeros(len(idx))
        if depth is not None:
            keep = np.isfinite(d) & (d > 0)
            idx, xi, eta, d = idx[keep], xi[keep], eta[keep], d[keep]
        better = (d < best_d[idx]) if depth is not None else ~found[idx]
        idx, xi, eta, d = idx[better], xi[better], eta[better], d[better]
        best_xi[idx], best_eta[idx], best_d[idx] = xi, eta, d
        found[idx] = True
    return best_xi, best_eta, found


def intersect_ray(P: np.ndarray, xn: np.ndarray, n: int = 2):
    """Nearest intersection of the rays (xn, 1) (xn (K, 2), normalized undistorted) with the
    patches P (K, 9, 3) (camera frame, mm): Newton in the ray-orthogonal 2-D problem
    P_xy − xn·P_z = 0 (as :func:`glsim.scene.bilinear.intersect_ray_patch` for Q4), started
    from the intersections with the patch's n × n bilinear sub-quads. Returns (ξ, η, Z, ok);
    ok needs a root with |ξ|, |η| ≤ 1 + INSIDE_TOL in front of the camera."""
    p2 = P[..., :2] - xn[:, None, :] * P[..., 2:3]
    xi, eta, ok = invert(p2, np.zeros((len(xn), 2)), lambda i, x, e: evaluate(P[i, :, 2:], x, e)[:, 0], n)
    Z = np.where(ok, evaluate(P[..., 2:], xi, eta)[:, 0], np.inf)
    return xi, eta, Z, ok


def folded(P: np.ndarray, n: int = 7) -> np.ndarray:
    """Patches (M, 9, 3) whose surface normal X_ξ × X_η reverses somewhere on an n × n grid
    of (ξ, η) (a fold, e.g. from a mid-side node moved too far), bool (M,). Normals shorter
    than 1e-9 of the largest (a collapsed T6 edge) are ignored."""
    t = np.linspace(-1, 1, n)
    xi, eta = (a.ravel() for a in np.meshgrid(t, t))
    da, db = shape_derivatives(xi, eta)
    out = np.zeros(len(P), bool)
    for s in range(0, len(P), 1 << 14):
        Q = P[s:s + (1 << 14)]
        Na = np.cross(np.einsum("gi,mid->mgd", da, Q), np.einsum("gi,mid->mgd", db, Q))   # (m, g, 3)
        ref = Na.sum(axis=1, keepdims=True)
        length = np.linalg.norm(Na, axis=-1)
        big = length > 1e-9 * length.max(axis=1, keepdims=True)
        out[s:s + len(Q)] = ((np.einsum("mgd,mgd->mg", Na, np.broadcast_to(ref, Na.shape)) <= 0) & big).any(axis=1)
    return out


# --- linear pieces ----------------------------------------------------------------------------

class Pieces:
    """A quadratic mesh cut into n × n bilinear Q4 pieces per patch (what the ``fast`` mode
    draws): ``mesh`` (a :class:`PiecesMesh`, the linear mesh of the pieces; their nodes are the
    patches evaluated on the n+1 grid, shared between neighbouring patches along common edges
    and corners so the pieces stay watertight), ``parent`` (K,) the patch of each piece, ``i``,
    ``j`` (K,) its place in the patch's grid."""

    def __init__(self, mesh, parent, i, j, n):
        self.mesh, self.parent, self.i, self.j, self.n = mesh, parent, i, j, n

    def to_parent(self, piece, xi_s, eta_s):
        """(patch, ξ, η) from (piece, ξs, ηs)."""
        xi, eta = to_parent(self.i[piece], self.j[piece], self.n, xi_s, eta_s)
        return self.parent[piece], xi, eta


class PiecesMesh:
    """The pieces as the linear mesh the drawing code takes (``nodes``, ``quads``,
    ``node_labels``, ``element_labels``, ``deformed(step)``, as :class:`~glsim.scene.mesh.Mesh`):
    the deformed nodes are evaluated from the source mesh's displacements when a step is drawn
    (the last STEPS_CACHED kept), so the pieces do not hold every load step."""
    STEPS_CACHED = 2
    patches = None
    is_quadratic = False

    def __init__(self, source, weights, src_patch, nodes, quads, element_labels):
        self.source, self._w, self._src = source, weights, src_patch
        self.nodes, self.quads = nodes, quads
        self.node_labels = np.arange(1, len(nodes) + 1)
        self.element_labels = element_labels
        self._steps: dict = {}

    n_nodes = property(lambda self: len(self.nodes))
    n_elements = property(lambda self: len(self.quads))
    n_steps = property(lambda self: self.source.n_steps)
    step_times = property(lambda self: self.source.step_times)

    def at_grid(self, values: np.ndarray) -> np.ndarray:
        """Per-node values of the source mesh (N, D) → at the pieces' nodes (K, D)."""
        return np.einsum("ki,kid->kd", self._w, patch_points(self.source.patches, values)[self._src])

    def grid_matrix(self):
        """:meth:`at_grid` as a scipy CSR matrix (K × N): the pieces' nodes as weights of the
        source mesh's nodes (derived centres spread: :func:`fold_centres`)."""
        from scipy import sparse

        cols, w = fold_centres(np.asarray(self.source.patches)[self._src], self._w)
        rows = np.repeat(np.arange(len(cols)), cols.shape[1])
        return sparse.csr_matrix((w.ravel(), (rows, cols.ravel())), shape=(len(cols), self.source.n_nodes))

    def deformed(self, step: int) -> np.ndarray:
        """The pieces' nodes (K, 3) mm at load step ``step``."""
        if step not in self._steps:
            base = self.source.deformed(step)          # validates step
            keep(self._steps, step, self.nodes + self.at_grid(base - self.source.nodes), self.STEPS_CACHED)
        return self._steps[step]


def linearize(mesh, n: int) -> Pieces:
    """The :class:`Pieces` of a quadratic ``mesh`` (``mesh.patches`` set), n × n per patch."""
    pt = np.asarray(mesh.patches)
    M = len(pt)
    t = np.linspace(-1, 1, n + 1)
    xi, eta = np.meshgrid(t, t)                       # [j, i]
    W = shape_functions(xi, eta).reshape(-1, 9)       # grid point g = j·(n+1) + i
    jj, ii = (a.ravel() for a in np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij"))
    # a key per (patch, grid point): corners by node, edge points by (edge's nodes, distance
    # from the lower corner), interior points by (patch, i, j)
    keys = np.zeros((M, len(W), 5), np.int64)
    keys[:, :, 0] = 2
    keys[:, :, 1] = np.arange(M)[:, None]
    keys[:, :, 2] = ii
    keys[:, :, 3] = jj
    edges = ((jj == 0, 0, 1, 4, ii), (ii == n, 1, 2, 5, jj), (jj == n, 2, 3, 6, n - ii), (ii == 0, 3, 0, 7, n - jj))
    for on, a, b, mid, k in edges:
        g = np.flatnonzero(on)
        ca, cb, cm = pt[:, a, None], pt[:, b, None], pt[:, mid, None]
        kk = np.where(ca <= cb, k[g], n - k[g])
        lo, hi = np.minimum(ca, cb), np.maximum(ca, cb)
        key = np.stack(np.broadcast_arrays(np.ones_like(kk), lo, hi, cm, kk), -1)
        at_node = (kk == 0) | (kk == n) | (ca == cb)
        node = np.where(kk == 0, lo, hi)
        key = np.where(at_node[..., None], np.stack(np.broadcast_arrays(np.zeros_like(kk), node, node * 0,
                                                                        node * 0, node * 0), -1), key)
        keys[:, g] = key
    _, first, inverse = np.unique(keys.reshape(-1, 5), axis=0, return_index=True, return_inverse=True)
    inverse = inverse.reshape(M, len(W))
    src_patch, src_point = np.divmod(first, len(W))
    weights = W[src_point]
    nodes = np.einsum("ki,kid->kd", weights, patch_points(pt, mesh.nodes)[src_patch])
    g = (np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]).ravel()     # lower-left grid point of piece j·n + i
    quads = np.stack([inverse[:, g], inverse[:, g + 1], inverse[:, g + n + 2], inverse[:, g + n + 1]], -1).reshape(-1, 4)
    piece = np.arange(n * n)
    parent = np.repeat(np.arange(M), n * n)
    out = PiecesMesh(mesh, weights, src_patch, nodes, quads, np.asarray(mesh.element_labels)[parent])
    return Pieces(out, parent, np.tile(piece % n, M), np.tile(piece // n, M), n)
