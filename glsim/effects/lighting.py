"""Surface normals and the paper's Phong lighting (§2.2.1, eqs. 10–13), numpy float64.

Mirrored function for function in ``shaders/shade.glsl`` (``spot_factor``, ``phong``,
``combine``). Everything is in the rendering camera's frame (OpenCV axes, mm, camera at the
origin) and in grey levels as fractions of full scale: the paper's Table 1 values for an 8-bit
camera, I_a = −10 and I_i = 80 grey levels, are ``ambient=-10/255`` and ``intensity=80/255``.

The illumination at a surface point X with unit normal N is (eq. 13 summed over lights)

    I = I_a + Σ_i spot_i · I_i / (1 + k_i d_i²) · (k_r·max(N·L_i, 0) + k_s·[N·L_i > 0]·max(R_i·V, 0)^r)

with V = normalize(−X) the direction to the camera (the paper's C), L_i = normalize(pos_i − X)
the direction to light i, d_i = |pos_i − X|, R_i = 2(N·L_i)N − L_i the reflected light
direction (the paper's L_s) and r the shininess. A normal facing away from the camera
(N·V < 0) is flipped first: thin shells are seen from either side.

Spotlights: cosθ_i = dot(−L_i, dir_i) is the cosine of the angle between the spot axis and the
ray from the light to X. With a half-angle ``cutoff_deg`` and an edge width ``edge_deg`` the
spot factor is ``smoothstep(cos(cutoff), cos(cutoff − edge), cosθ)`` when edge > 0 (GLSL's
smoothstep, run in cos θ: 1 inside cutoff − edge, 0 outside the cutoff, 0.5 where cos θ is
midway between the two cosines), and a hard step when edge = 0: 1 for cosθ ≥ cos(cutoff),
else 0. Point lights have ``dir = 0`` and a spot factor of 1.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple, Sequence

import numpy as np

from glsim.errors import SceneError

DEGENERATE_SIN = 1e-12  # |d1 × d2| ≤ this · |d1|·|d2| (diagonals parallel): zero-area element


def _diagonal_cross(nodes, quads):
    nodes = np.asarray(nodes, dtype=np.float64)
    quads = np.asarray(quads, dtype=np.intp)
    x = nodes[quads]                                   # (M, 4, 3)
    d1 = x[:, 2] - x[:, 0]
    d2 = x[:, 3] - x[:, 1]
    c = np.cross(d1, d2)
    norm = np.linalg.norm(c, axis=-1)
    scale = np.linalg.norm(d1, axis=-1) * np.linalg.norm(d2, axis=-1)
    ok = (norm > DEGENERATE_SIN * scale) & (norm > 0) & np.isfinite(norm)
    return np.where(ok[:, None], c, 0.0), np.where(ok, norm, 0.0)


def element_normals(nodes, quads) -> np.ndarray:
    """Unit element normals (M, 3) from the cross product of the diagonals (x2−x0)×(x3−x1).

    For a planar quad |(x2−x0)×(x3−x1)|/2 is its area and the normal is exact; for a warped
    quad it is the normal of the average plane. Collapsed triangles (a, b, c, c) give their
    triangle's normal. Zero-area elements (diagonals parallel to within DEGENERATE_SIN, or of
    zero length) give (0, 0, 0), never NaN. The sign follows the corner order (counter-
    clockwise seen from the normal's tip).
    """
    c, norm = _diagonal_cross(nodes, quads)
    return c / np.where(norm > 0, norm, 1.0)[:, None]


def vertex_normals(nodes, quads) -> np.ndarray:
    """Per-node unit normals (N, 3): the area-weighted average of the adjacent elements'
    normals (weight |d1 × d2|/2, so the sum is Σ (d1 × d2)/2), normalised.

    An element counts once per distinct node (a collapsed triangle's repeated corner is not
    counted twice). Nodes with no usable element, or whose adjacent normals cancel, get
    (0, 0, 0).
    """
    nodes = np.asarray(nodes, dtype=np.float64)
    quads = np.asarray(quads, dtype=np.intp)
    acc, wsum, _ = _vertex_sums(quads, *_diagonal_cross(nodes, quads), len(nodes))
    return _normalised(acc, wsum)


def _vertex_sums(quads: np.ndarray, c: np.ndarray, norm: np.ndarray, n_nodes: int):
    """Per node the sums Σ c/2 (N, 3) and Σ |c|/2 (N,) over its elements (each once per distinct
    node), and the (nodes, elements) pairs summed, per corner slot."""
    acc, wsum, pairs = np.zeros((n_nodes, 3)), np.zeros(n_nodes), []
    for j in range(4):
        first = np.ones(len(quads), dtype=bool)
        for i in range(j):
            first &= quads[:, j] != quads[:, i]
        np.add.at(acc, quads[first, j], 0.5 * c[first])
        np.add.at(wsum, quads[first, j], 0.5 * norm[first])
        pairs.append((quads[first, j], np.flatnonzero(first)))
    return acc, wsum, pairs


def _normalised(acc: np.ndarray, wsum: np.ndarray) -> np.ndarray:
    """:func:`vertex_normals` from :func:`_vertex_sums`: 0 where the sums cancel."""
    n = np.linalg.norm(acc, axis=-1)
    ok = (n > DEGENERATE_SIN * wsum) & (n > 0)
    return np.where(ok[:, None], acc / np.where(ok, n, 1.0)[:, None], 0.0)


@dataclass(frozen=True)
class LightArrays:
    """Lights in the camera frame (mm), float64, one row per light.

    ``pos`` (L, 3) position; ``dir`` (L, 3) unit spotlight axis, all zeros for a point light;
    ``intensity`` (L,) I_i in fractions of full scale; ``attenuation`` (L,) k of 1/(1 + k d²)
    in 1/mm²; ``cos_cutoff`` (L,) cosine of the spot half-angle (−1 for a point light);
    ``cos_inner`` (L,) cosine of (cutoff − edge), where the smooth edge reaches 1
    (= cos_cutoff for a hard edge).
    """
    pos: np.ndarray
    dir: np.ndarray
    intensity: np.ndarray
    attenuation: np.ndarray
    cos_cutoff: np.ndarray
    cos_inner: np.ndarray

    def __len__(self) -> int:
        return len(self.intensity)


def _get(light: Any, name: str, default=None):
    if isinstance(light, dict):
        return light.get(name, default)
    return getattr(light, name, default)


def lights_to_camera(lights_world: Sequence[Any], R=None, t=None) -> LightArrays:
    """World-frame light descriptions → LightArrays in the camera frame X_cam = R·X_world + t.

    Each light is a dict or an object with ``position`` (mm), ``direction`` (spot axis, any
    length; None or omitted for a point light), ``intensity`` (fraction of full scale),
    ``attenuation`` (k, 1/mm²; default 0), ``cutoff_deg`` (spot half-angle, degrees, in
    (0, 180]; 180 or omitted = point light) and ``edge_deg`` (width of the smooth edge inside
    the cutoff, degrees, in [0, cutoff]; default 0 = hard edge). R, t default to the identity
    (camera 0 is the world frame). Bad values raise SceneError naming ``lights[i].key``.
    """
    R = np.eye(3) if R is None else np.asarray(R, dtype=np.float64)
    t = np.zeros(3) if t is None else np.asarray(t, dtype=np.float64)
    pos, dirs, inten, att, cc, ci = [], [], [], [], [], []
    for i, light in enumerate(lights_world):
        key = f"lights[{i}]"
        p = _get(light, "position")
        if p is None or np.shape(p) != (3,) or not np.isfinite(np.asarray(p, float)).all():
            raise SceneError(f"{key}.position", f"must be 3 finite numbers, got {p!r}",
                             "give the light's position in mm in the world frame")
        intensity = float(_get(light, "intensity", 0.0))
        if not np.isfinite(intensity):
            raise SceneError(f"{key}.intensity", f"must be finite, got {intensity}",
                             "give I_i as a fraction of full scale (80 grey levels of 8 bits = 80/255)")
        k = float(_get(light, "attenuation", 0.0) or 0.0)
        if not (np.isfinite(k) and k >= 0):
            raise SceneError(f"{key}.attenuation", f"must be ≥ 0, got {k}", "k of 1/(1 + k d²), in 1/mm²")
        d = _get(light, "direction")
        cutoff = _get(light, "cutoff_deg")
        cutoff = 180.0 if cutoff is None else float(cutoff)
        edge = float(_get(light, "edge_deg", 0.0) or 0.0)
        if not 0 < cutoff <= 180:
            raise SceneError(f"{key}.cutoff_deg", f"must be in (0, 180], got {cutoff}",
                             "the spot's half-angle in degrees (180 = point light)")
        if d is None or cutoff == 180.0:
            d_cam = np.zeros(3)
            cos_c = cos_i = -1.0
        else:
            d = np.asarray(d, dtype=np.float64)
            if d.shape != (3,) or not np.isfinite(d).all() or np.linalg.norm(d) == 0:
                raise SceneError(f"{key}.direction", f"must be a non-zero 3-vector, got {d!r}",
                                 "give the spotlight's axis, or leave it out for a point light")
            if not 0 <= edge <= cutoff:
                raise SceneError(f"{key}.edge_deg", f"must be in [0, cutoff_deg = {cutoff}], got {edge}",
                                 "the width in degrees of the smooth edge inside the cutoff (0 = hard)")
            d_cam = R @ (d / np.linalg.norm(d))
            d_cam /= np.linalg.norm(d_cam)
            cos_c = np.cos(np.radians(cutoff))
            cos_i = np.cos(np.radians(cutoff - edge))
        pos.append(R @ np.asarray(p, dtype=np.float64) + t)
        dirs.append(d_cam)
        inten.append(intensity)
        att.append(k)
        cc.append(cos_c)
        ci.append(cos_i)
    f = lambda v, shape: np.asarray(v, dtype=np.float64).reshape(shape)  # noqa: E731
    n = len(pos)
    return LightArrays(f(pos, (n, 3)), f(dirs, (n, 3)), f(inten, (n,)), f(att, (n,)), f(cc, (n,)), f(ci, (n,)))


def spot_factor(cos_theta, cos_cutoff, cos_inner):
    """Spotlight factor: smoothstep(cos_cutoff, cos_inner, cosθ) when cos_inner > cos_cutoff,
    the hard step [cosθ ≥ cos_cutoff] otherwise."""
    cos_theta, cos_cutoff, cos_inner = np.broadcast_arrays(
        *(np.asarray(a, dtype=np.float64) for a in (cos_theta, cos_cutoff, cos_inner)))
    smooth = cos_inner > cos_cutoff
    width = np.where(smooth, cos_inner - cos_cutoff, 1.0)
    s = np.clip((cos_theta - cos_cutoff) / width, 0.0, 1.0)
    return np.where(smooth, s * s * (3.0 - 2.0 * s), (cos_theta >= cos_cutoff).astype(np.float64))


def _normalize(v):
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.where(n > 0, v / np.where(n > 0, n, 1.0), 0.0), n[..., 0]


class ShadingGeometry(NamedTuple):
    """Per point (…) and light (…, L) of :func:`phong`: the unit normal Nu and its length m, the
    flip (±1) that turns it to the camera and the turned normal N, the view direction V and
    |X| x, the light directions L and distances d, N·L, R − V, s = 1 − R·V, where the specular
    term is on (``lit``) and its value, cos θ to the spot axes, the spot factors, the attenuated
    intensities."""
    Nu: np.ndarray
    m: np.ndarray
    flip: np.ndarray
    N: np.ndarray
    V: np.ndarray
    x: np.ndarray
    L: np.ndarray
    d: np.ndarray
    nl: np.ndarray
    RmV: np.ndarray
    s: np.ndarray
    lit: np.ndarray
    spec: np.ndarray
    cos_theta: np.ndarray
    spot: np.ndarray
    att: np.ndarray


def geometry(X, N, lights: LightArrays, shininess: float) -> ShadingGeometry:
    """:class:`ShadingGeometry` at camera-frame points X and normals N (…, 3, broadcast; N need not be
    unit, N = 0 gives zero directions). The specular power is taken only where N·L > 0 and
    R·V > 0 (so shininess 0 gives k_s·[R·V > 0], not 0⁰), as exp(r·log(1 − s)) with s = |R − V|²/2
    = 1 − R·V for unit R, V: the same number, but in float32 (the shader) it keeps its relative
    accuracy at the highlight, where 1 − R·V is tiny and a plain dot product near 1 loses r·2⁻²⁴."""
    X = np.asarray(X, dtype=np.float64)
    Nu, m = _normalize(np.asarray(N, dtype=np.float64))
    X, Nu = np.broadcast_arrays(X, Nu)
    V, x = _normalize(-X)
    flip = np.where(_dot(Nu, V) < 0, -1.0, 1.0)
    Nf = Nu * flip[..., None]
    L, d = _normalize(lights.pos - X[..., None, :])                  # (…, L, 3), (…, L)
    nl = _dot(Nf[..., None, :], L)
    RmV = 2.0 * nl[..., None] * Nf[..., None, :] - L - V[..., None, :]
    s = 0.5 * _dot(RmV, RmV)                                          # 1 − R·V
    lit = (nl > 0) & (s < 1)                                          # N·L > 0 and R·V > 0
    spec = np.where(lit, np.exp(shininess * np.log1p(-np.where(lit, s, 0.0))), 0.0)
    cos_theta = _dot(-L, lights.dir)
    is_spot = np.any(lights.dir != 0, axis=-1)
    spot = np.where(is_spot, spot_factor(cos_theta, lights.cos_cutoff, lights.cos_inner), 1.0)
    att = lights.intensity / (1.0 + lights.attenuation * d * d)
    return ShadingGeometry(Nu, m, flip, Nf, V, x, L, d, nl, RmV, s, lit, spec, cos_theta, spot, att)


def phong(X, N, lights: LightArrays, ambient: float, k_r: float, k_s: float, shininess: float):
    """The paper's eq. 13 summed over ``lights``, in fractions of full scale (see module doc).

    X (..., 3) surface points and N (..., 3) normals in the camera frame; returns I (...).
    N is normalised here (interpolated normals need not be unit); N = 0 (degenerate) gives the
    ambient term only. The specular term as :func:`geometry` takes it."""
    g = geometry(X, N, lights, shininess)
    return ambient + np.sum(g.spot * g.att * (k_r * np.maximum(g.nl, 0.0) + k_s * g.spec), axis=-1)


MODELS = ("additive", "multiplicative")


def combine(grey, I, model: str = "additive"):
    """Lit grey level: ``"additive"`` → grey + I (the paper adds grey levels);
    ``"multiplicative"`` → grey · I (physically based: albedo × irradiance, I = 1 is the unlit
    reference brightness). Not clipped: saturation is clipped and reported at quantisation."""
    grey = np.asarray(grey, dtype=np.float64)
    I = np.asarray(I, dtype=np.float64)
    if model == "additive":
        return grey + I
    if model == "multiplicative":
        return grey * I
    raise ValueError(f"lighting model must be one of {MODELS}, got {model!r}")


def saturated_fraction(image) -> float:
    """Fraction of pixels at or beyond full scale (≥ 1) or at or below black (≤ 0)."""
    image = np.asarray(image)
    if image.size == 0:
        return 0.0
    return float(np.count_nonzero((image >= 1) | (image <= 0)) / image.size)


# ---- derivatives (image Jacobians, glsim.imaging.jacobian) ----------------------------------------

def _dot(a, b):
    return np.einsum("...d,...d->...", a, b)


def _unit_derivative(u, length):
    """∂(v/|v|)/∂v (..., 3, 3) = (I − u uᵀ)/|v| at the unit u = v/|v| of length ``length``
    (zero where it is 0)."""
    inv = np.divide(1.0, length, out=np.zeros_like(length), where=length > 0)
    return (np.eye(3) - u[..., :, None] * u[..., None, :]) * inv[..., None, None]


def phong_gradient(X, N, lights: LightArrays, ambient: float, k_r: float, k_s: float, shininess: float):
    """:func:`phong` (I (n,)), its derivatives with respect to the point X and the normal N as
    given (not necessarily unit), and the part of ∂I/∂X that comes through the view direction V
    alone (moving the camera by −δ changes I by it · δ), each (n, 3), camera frame, per mm and
    per unit of N. X, N: (n, 3). Exact wherever :func:`phong` is smooth: not where N·L = 0,
    R·V = 0, N·V = 0 (the flip), on a hard spot edge or at the smooth edge's ends (there the
    one-sided value the branch taken gives). N = 0 gives I = ambient and zero derivatives."""
    g = geometry(X, N, lights, shininess)
    Nf, V, L, d, nl, RmV, lit, spec, cos_theta, spot, att = (g.N, g.V, g.L, g.d, g.nl, g.RmV, g.lit, g.spec,
                                                             g.cos_theta, g.spot, g.att)
    dNf = _unit_derivative(g.Nu, g.m) * g.flip[:, None, None]          # ∂Nf/∂N (n, 3, 3)
    dV = -_unit_derivative(V, g.x)                                    # ∂V/∂X
    dL = -_unit_derivative(L, d)                                      # ∂L/∂X (n, L, 3, 3)
    nv = _dot(Nf, V)[:, None]
    dspec = np.where(lit, shininess * spec / np.where(lit, 1.0 - g.s, 1.0), 0.0)   # ∂spec/∂(R·V)
    dnl_X = np.einsum("nd,nlde->nle", Nf, dL)                        # ∂(N·L)/∂X
    # R·V = 2 (N·L)(N·V) − L·V
    drv_X = (2.0 * nv[..., None] * dnl_X + 2.0 * nl[..., None] * np.einsum("nd,nde->ne", Nf, dV)[:, None]
             - np.einsum("nld,nde->nle", L, dV) - np.einsum("nd,nlde->nle", V, dL))
    drv_N = 2.0 * nv[..., None] * L + 2.0 * nl[..., None] * V[:, None]    # ∂(R·V)/∂Nf
    smooth = np.any(lights.dir != 0, axis=-1) & (lights.cos_inner > lights.cos_cutoff)
    width = np.where(smooth, lights.cos_inner - lights.cos_cutoff, 1.0)
    t = (cos_theta - lights.cos_cutoff) / width
    dspot = np.where(smooth & (t > 0) & (t < 1), 6.0 * t * (1.0 - t) / width, 0.0)   # ∂spot/∂cosθ
    dcos_X = -np.einsum("ld,nlde->nle", lights.dir, dL)
    k_d2 = 1.0 + lights.attenuation * d * d
    datt_X = (2.0 * lights.intensity * lights.attenuation * d / (k_d2 * k_d2))[..., None] * L   # ∂d/∂X = −L
    body = k_r * np.maximum(nl, 0.0) + k_s * spec
    dbody_X = k_r * (nl > 0)[..., None] * dnl_X + k_s * dspec[..., None] * drv_X
    dbody_N = k_r * (nl > 0)[..., None] * L + k_s * dspec[..., None] * drv_N
    I = ambient + np.sum(spot * att * body, axis=-1)
    dI_X = np.sum((dspot * att * body)[..., None] * dcos_X + (spot * body)[..., None] * datt_X
                  + (spot * att)[..., None] * dbody_X, axis=1)
    dI_N = np.einsum("nd,nde->ne", np.sum((spot * att)[..., None] * dbody_N, axis=1), dNf)
    dI_V = np.einsum("nd,nde->ne", np.sum((spot * att * k_s * dspec)[..., None] * (RmV + V[:, None]), axis=1), dV)
    return I, dI_X, dI_N, dI_V


def _cross_matrix(a):
    """[a]× (..., 3, 3): [a]× b = a × b."""
    out = np.zeros(a.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2], out[..., 1, 2] = -a[..., 2], a[..., 1], -a[..., 0]
    out[..., 1, 0], out[..., 2, 0], out[..., 2, 1] = a[..., 2], -a[..., 1], a[..., 0]
    return out


def _cross_derivatives(nodes, quads):
    """The diagonals' cross product c = (x2 − x0) × (x3 − x1) of each element (M, 3), its norm
    and ∂c/∂x_k (M, 4, 3, 3) for the 4 corners (c and ∂c zero where :func:`_diagonal_cross`
    finds the element degenerate)."""
    x = np.asarray(nodes, np.float64)[np.asarray(quads, np.intp)]
    d1, d2 = x[:, 2] - x[:, 0], x[:, 3] - x[:, 1]
    c, norm = _diagonal_cross(nodes, quads)
    A, B = _cross_matrix(d1), _cross_matrix(d2)
    return c, norm, np.stack([B, -A, -B, A], axis=1) * (norm > 0)[:, None, None, None]


def normal_jacobian(nodes, quads, flat: bool):
    """The derivative of the lighting's normals with respect to the node positions, world
    frame, as scipy CSR: rows 3·i + a for component a of element i's normal
    (:func:`element_normals`, ``flat``) or of node i's (:func:`vertex_normals`), columns
    3·j + b for node j's position. Zero for zero-area elements and nodes without a normal."""
    from scipy import sparse

    quads = np.asarray(quads, np.intp)
    M, n_nodes = len(quads), len(nodes)
    c, norm, dc = _cross_derivatives(nodes, quads)
    cols = (3 * quads[:, :, None] + np.arange(3)).reshape(M, 1, 12)      # (element, corner·b)
    if flat:
        u = c / np.where(norm > 0, norm, 1.0)[:, None]
        block = np.einsum("mab,mkbc->makc", _unit_derivative(u, norm), dc)   # (M, 3, 4, 3)
        rows = np.broadcast_to((3 * np.arange(M)[:, None] + np.arange(3))[:, :, None], (M, 3, 12))
        return sparse.csr_matrix((block.reshape(M, 3, 12).ravel(), (rows.ravel(), np.broadcast_to(cols, (M, 3, 12)).ravel())),
                                 shape=(3 * M, 3 * n_nodes))
    acc, wsum, parts = _vertex_sums(quads, c, norm, n_nodes)   # each element once per distinct node
    n = _normalised(acc, wsum)
    P = _unit_derivative(n, np.where(np.any(n != 0, axis=1), np.linalg.norm(acc, axis=1), 0.0))   # (N, 3, 3)
    data, rows, col = [], [], []
    for node, e in parts:
        block = 0.5 * np.einsum("mab,mkbc->makc", P[node], dc[e]).reshape(len(e), 3, 12)
        data.append(block.ravel())
        rows.append(np.broadcast_to((3 * node[:, None] + np.arange(3))[:, :, None], block.shape).ravel())
        col.append(np.broadcast_to(cols[e], block.shape).ravel())
    J = sparse.coo_matrix((np.concatenate(data), (np.concatenate(rows), np.concatenate(col))),
                          shape=(3 * n_nodes, 3 * n_nodes)).tocsr()
    J.sum_duplicates()
    return J


@dataclass(frozen=True, eq=False)
class ShadingTerms:
    """What the lighting adds to an image Jacobian (:func:`glsim.imaging.jacobian.image_jacobian`),
    for one camera and state: the lit grey g' = combine(g, I(X, Ñ)) of a sample with reference
    grey g, point X and interpolated normal Ñ = Σ N_k n_k (camera frame).

    ``corners`` (M, 4, 3): the corner normals n_k in the camera frame (unit, as rendered) of
    the elements, or of a quadratic mesh's linear pieces (``pieces`` per side; the normal is
    interpolated over the piece holding the sample); ``source`` (M, 4): the row block of each
    corner's normal in :meth:`D` (its node's, smooth; its element's, flat); ``nodes`` (world mm),
    ``quads`` and ``flat``: what the normals are made from; ``grid``: the pieces' nodes as weights of the
    mesh's (CSR) or None; ``grey(uv)``: the reference interpolant's values (a multiplicative
    combination needs them)."""
    lighting: Any
    lights: LightArrays
    corners: np.ndarray
    source: np.ndarray
    nodes: np.ndarray
    quads: np.ndarray
    flat: bool
    grid: Any
    grey: Any
    pieces: int = 0

    @property
    def sources(self) -> int:
        """Row blocks of :meth:`D`: the elements' (flat) or the nodes' normals."""
        return len(self.quads) if self.flat else len(self.nodes)

    def D(self, needed):
        """The normals' derivative with respect to the mesh's nodes, world frame (scipy CSR,
        3·sources × 3·nodes; :func:`normal_jacobian`, for pieces chained through ``grid``), made
        for the row blocks ``needed`` only (the others zero): from the elements whose normals
        (flat) or whose corners' normals (smooth) they are — a rolling shutter's row needs few."""
        from scipy import sparse

        quads, needed = np.asarray(self.quads, np.intp), np.unique(needed)
        if self.flat:
            block = normal_jacobian(self.nodes, quads[needed], True).tocoo()
            rows = 3 * needed[block.row // 3] + block.row % 3
            D = sparse.csr_matrix((block.data, (rows, block.col)), shape=(3 * len(quads), 3 * len(self.nodes)))
        else:
            keep = np.zeros(len(self.nodes), bool)
            keep[needed] = True
            D = sparse.diags(np.repeat(keep, 3).astype(np.float64)) @ normal_jacobian(
                self.nodes, quads[keep[quads].any(axis=1)], False)
        return D if self.grid is None else D @ sparse.kron(self.grid, sparse.identity(3), format="csr")

    def normals_at(self, e, xi, eta):
        """The interpolated normal Ñ (n, 3, camera frame) at element e's (ξ, η), ∂Ñ/∂(ξ, η)
        (n, 3, 2), and the ``source`` rows (n, 4) and weights (n, 4) of the corner normals it
        blends."""
        from glsim.scene import bilinear as bl
        from glsim.scene.quadratic import piece_of

        piece, xs, ys, scale = (e, xi, eta, 1.0) if not self.pieces else (*piece_of(e, xi, eta, self.pieces),
                                                                          float(self.pieces))
        nk, w = self.corners[piece], bl.shape_functions(xs, ys)
        dxs, dys = bl.shape_derivatives(xs, ys)
        dN = np.stack([np.einsum("nk,nkd->nd", dxs, nk), np.einsum("nk,nkd->nd", dys, nk)], -1) * scale
        return np.einsum("nk,nkd->nd", w, nk), dN, self.source[piece], w

    def terms(self, r, X, N):
        """(∂g'/∂g (n,), ∂g'/∂X, ∂g'/∂Ñ, ∂g'/∂X through the view direction alone (each (n, 3):
        :func:`phong_gradient`)) at reference points r (n, 2) px, points X and interpolated
        normals Ñ (n, 3, camera frame)."""
        lit = self.lighting
        I, *dI = phong_gradient(X, N, self.lights, lit.ambient, lit.diffuse, lit.specular, lit.shininess)
        if lit.combine == "additive":
            return (np.ones(len(I)), *dI)
        g = self.grey(r)[:, None]
        return (I, *(g * d for d in dI))
