"""Closed-form bounds of the GL path's error against the CPU oracle, derived from the arithmetic
of each mode: functions of numbers, cameras and arrays that build no renderer, for ``glsim check``
and the GL tests — the same bounds on llvmpipe and on a GPU. The camera passes' (vignetting, PSF,
fixed pattern): :func:`camera_passes`; the float32 passes' against their float64 twins under GLSL
4.50's precision rules: the lighting (:func:`phong`), the depth of field's circle of confusion
(:func:`coc`) and gathers (:func:`blur`), a reference sample (:func:`interpolation`), the sensor
noise's normal field (:func:`standard_normal`) and pass (:func:`noise`). Where the two may decide
a sample's coverage the other way: :func:`tie_px`, :func:`near_edges`; an image's grey levels
elsewhere: :func:`grey`. The same bounds over a scene's pixels, from the oracle's own maps of it:
:mod:`glsim.check.oracle_maps`.

- **float64 (exact, q4, and their truth)**: unit roundoff 2^-53 = 1.1e-16 on coordinates below
  1e4 (px or mm) is 1.1e-12; the closed-form roots, two Newton polishes and the projections
  multiply it by their conditioning, below 1e3 for any element the tie rule lets through
  (folded and grazing ones included); ``FLOAT64`` = 1e-9 keeps a factor of ten on top.
- **float32 (fast)**: each vertex is projected in float32 — the camera transform R·x + t' of a
  node relative to the mesh's origin (terms up to the camera's distance D ≈ Z: 3 roundings per
  component, each ≤ 2^-24 of D), the division x/z, the distortion polynomial and the pixel
  mapping (about 6 more roundings relative to |xn| ≤ 1) — so a vertex lies within
  fx·12·2^-24 px of the oracle's; the float32 interpolation between the vertices (edge
  functions over differences < 2^8 px) adds under 1e-5 px. What moves a vertex by δ px moves
  an interpolated quantity by δ times its derivative per image pixel (:func:`per_pixel`): a
  reference point by δ·|∂ref/∂uv| (57× at a plate seen at 89°), a material point by δ·|∂X/∂uv|.
"""
from __future__ import annotations

import numpy as np

FLOAT64 = 1e-9                # px or mm: exact and q4 (reference points, truth X, ξ η-derived maps)
FLOAT32_ROUNDOFF = 2.0 ** -24


def fast_px(fx: float) -> float:
    """Bound (px) of a fast-mode vertex's image position against the oracle's, camera focal
    length ``fx`` px (module docstring)."""
    return fx * 12 * FLOAT32_ROUNDOFF + 1e-5


def per_pixel(field: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """|∂field/∂(u, v)| per pixel (H, W): the largest norm of the differences to its four
    neighbours that are also in ``mask``; a pixel without such a neighbour takes the largest
    value of the image. ``field`` (H, W, k)."""
    out = np.full(mask.shape, -1.0)
    for axis in (0, 1):
        n = mask.shape[axis]
        d = np.linalg.norm(np.diff(field, axis=axis), axis=-1)
        ok = np.take(mask, range(n - 1), axis) & np.take(mask, range(1, n), axis)
        d = np.where(ok, d, -1.0)
        for pad in ((1, 0), (0, 1)):   # the difference to the previous pixel, then to the next
            out = np.maximum(out, np.pad(d, [pad if a == axis else (0, 0) for a in (0, 1)], constant_values=-1.0))
    seen = out >= 0
    return np.where(seen, out, out[seen].max() if seen.any() else 0.0)


def interpolated(px, field: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Per pixel: the bound of a quantity a float32 build interpolates over its elements' corners
    (a reference point in px or a material point in mm; ``field`` the oracle's map of it,
    (H, W, k)) against the oracle's, where its sample point in the image lies within ``px`` of
    the oracle's: px·|∂field/∂(u, v)| (:func:`per_pixel`), plus the corners' values stored in
    float32 and their weighted sum (Σ w = 1, w ≥ 0: within 4u of the largest |value|, u = 2^-24;
    5u√k of the map's largest norm)."""
    k = field.shape[-1]
    top = float(np.linalg.norm(field[mask], axis=-1).max()) if mask.any() else 0.0
    return px * per_pixel(field, mask) + 5 * FLOAT32_ROUNDOFF * np.sqrt(k) * top + FLOAT64


def fast_bound(fx: float, field: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Per pixel: the bound of a fast-mode quantity interpolated over the vertices against the
    oracle's (:func:`interpolated` at the vertices' :func:`fast_px`)."""
    return interpolated(fast_px(fx), field, mask)


NEWTON_TOL_FP32 = 1e-6   # shaders/bilinear.glsl's NEWTON_TOL in a float32 build (ξ, η)


def q4_fp32_px(cam, nodes: np.ndarray, quads: np.ndarray) -> float:
    """Bound (px) of where a float32 q4 build maps a sample, against the oracle: its elements'
    corners projected in float32 as fast's vertices (:func:`fast_px`); invert_newton's
    coordinates relative to corner 0, p_i − p_0 and q − p_0, each rounded (u·|coordinate|, up to
    the largest projected corner or image corner: 2u·P); its stopping step NEWTON_TOL_FP32 in
    (ξ, η) times the largest element extent E in px, and its float32 residual on those
    relative coordinates (4u·E). ``nodes`` (N, 3) world mm at the step."""
    from glsim.scene.camera import project

    uv, ok = project(nodes, cam)
    corners = uv[quads][ok[quads].all(axis=1)]
    if not len(corners):
        return fast_px(cam.fx)
    P = max(float(np.abs(corners).max()), float(np.hypot(*cam.size)))
    E = float(np.linalg.norm(corners - corners[:, :1], axis=-1).max())
    u = FLOAT32_ROUNDOFF
    return fast_px(cam.fx) + 2 * u * P + NEWTON_TOL_FP32 * E + 4 * u * E


def mapping(mode: str, fx: float, field: np.ndarray, mask: np.ndarray):
    """The bound of a GL map (reference points in px, material points in mm) against the
    oracle's in ``mode``: FLOAT64 in exact and q4, per pixel :func:`fast_bound` (``field`` the
    oracle's map, camera focal length ``fx`` px) in fast. (q4's float32 build:
    :func:`interpolated` at :func:`q4_fp32_px`.)"""
    return fast_bound(fx, field, mask) if mode == "fast" else FLOAT64


def tie_px(mode: str, fx: float, subpixel_bits: int | None) -> float:
    """How far (px) from an element edge a sample may legitimately be covered differently by GL
    and the oracle: exact and q4 decide coverage in float64 from the same float64 corners
    (FLOAT64); fast rasterizes its float32 vertices (:func:`fast_px` from the oracle's) after
    snapping them to the rasterizer's sub-pixel grid, ``subpixel_bits`` (GL_SUBPIXEL_BITS): a
    vertex moves by at most 2^-(bits+1) per axis, so under 2^-bits px, and an edge by at most what
    its ends move."""
    if mode != "fast":
        return FLOAT64
    return fast_px(fx) + 2.0 ** -subpixel_bits


EDGE_PIECES = 32   # a distorted exact-mode edge: pieces of its polyline (:func:`near_edges`)


def near_edges(cam, nodes: np.ndarray, quads: np.ndarray, radius, spp: int = 1,
               exact: bool = False) -> np.ndarray:
    """(H, W) bool: the pixels with a sample (:func:`glsim.scene.camera.pixel_grid`'s s×s points)
    within ``radius`` px of an element edge as ``cam`` projects it — the pixels where a coverage
    tie (:func:`tie_px`) may change a sample's element, or cover it or not (the silhouette).
    ``nodes`` (N, 3) world mm, ``quads`` (M, 4). The edges are straight between their projected
    ends, as fast and q4 draw them (edges with an end the camera cannot project left out: those
    modes drop their elements). With ``exact``, the exact mode's edges, which it intersects per
    pixel: under distortion each is imaged as a curve — a polyline of EDGE_PIECES projected
    points, the radius widened by its largest second difference |p₋ − 2p + p₊| (the chords'
    deviation from the curve is about an eighth of it), edges with a point it cannot project left
    out; through a pinhole, an edge that crosses the camera plane is imaged as a half-line from
    its end in front (drawn to LONG_PX beyond it). ``radius``: px, or a function of the edges'
    node indices (a, b) giving each its own (:func:`glsim.check.exact32.edge_px`)."""
    from glsim.scene.camera import project, to_camera

    s = int(round(np.sqrt(spp)))
    W, H = cam.size
    pairs = np.sort(np.stack([quads, np.roll(quads, -1, axis=1)], -1).reshape(-1, 2), axis=1)
    a, b = np.unique(pairs, axis=0).T
    radius = radius(a, b) if callable(radius) else np.full(len(a), float(radius))
    if exact and np.any(cam.distortion.coeffs != 0):
        t = np.linspace(0.0, 1.0, EDGE_PIECES + 1)
        P = nodes[a, None] * (1 - t[None, :, None]) + nodes[b, None] * t[None, :, None]
        uv, ok = project(P.reshape(-1, 3), cam)
        uv, ok = uv.reshape(len(a), -1, 2), ok.reshape(len(a), -1).all(axis=1)
        bend = np.linalg.norm(uv[:, :-2] - 2 * uv[:, 1:-1] + uv[:, 2:], axis=-1).max(axis=1)
        A, B = uv[ok, :-1].reshape(-1, 2), uv[ok, 1:].reshape(-1, 2)
        r = np.repeat(radius[ok] + bend[ok], EDGE_PIECES)
    else:
        uv, ok = project(nodes, cam)
        keep = ok[a] & ok[b]
        A, B, r = uv[a[keep]], uv[b[keep]], radius[keep]
        if exact:
            starts, ends, crossing = _half_lines(to_camera(nodes, cam), a, b, cam)
            A, B, r = np.concatenate([A, starts]), np.concatenate([B, ends]), np.concatenate([r, radius[crossing]])
    hit = np.zeros((H * s, W * s), bool)
    steep = np.abs(B[:, 1] - A[:, 1]) > np.abs(B[:, 0] - A[:, 0])
    for axis in (0, 1):   # walk a segment's sample columns (mostly horizontal) or rows (steep)
        sel = steep if axis else ~steep
        _mark(hit if axis == 0 else hit.T, A[sel][:, [axis, 1 - axis]], B[sel][:, [axis, 1 - axis]], r[sel], s)
    return hit.reshape(H, s, W, s).any(axis=(1, 3))


LONG_PX = 1e7   # a half-line's drawn length (px): beyond any image (glsim.limits)


def _half_lines(Xc: np.ndarray, a: np.ndarray, b: np.ndarray, cam) -> tuple[np.ndarray, np.ndarray]:
    """Through a pinhole ``cam``, the images of the edges a→b (node indices; ``Xc`` the nodes
    in its frame, mm) that cross its plane: from the projection of the end in front (z > 0)
    along the image of the edge toward the end behind, LONG_PX long — the front part's image
    is that half-line, reaching infinity where the edge meets z = 0. Returns (starts, ends) and
    the indices of their edges in a, b."""
    from glsim.scene.camera import project_camera_frame

    za, zb = Xc[a, 2], Xc[b, 2]
    cross = (za > 0) != (zb > 0)
    front = np.where(za[cross] > 0, a[cross], b[cross])
    back = np.where(za[cross] > 0, b[cross], a[cross])
    P, Q = Xc[front], Xc[back]
    zc = P[:, 2:] / (P[:, 2:] - Q[:, 2:])          # the crossing's parameter along P→Q, in (0, 1]
    near = P + 0.5 * zc * (Q - P)                  # halfway to the crossing: still in front
    (p, _), (q, _) = project_camera_frame(P, cam), project_camera_frame(near, cam)
    d = q - p
    n = np.linalg.norm(d, axis=1)
    ok = n > 0                                      # (an edge on a ray through the centre: a point)
    return p[ok], p[ok] + d[ok] / n[ok, None] * LONG_PX, np.flatnonzero(cross)[ok]


def _mark(hit: np.ndarray, A: np.ndarray, B: np.ndarray, r: np.ndarray, s: int) -> None:
    """Set ``hit`` (rows along y, columns along x: samples at (k + 0.5)/s − 0.5 px) where a
    sample lies within ``r`` of a segment A→B whose slope |Δy/Δx| ≤ 1. Each column x the segment
    (widened by r) spans is looked at: its point within r of the segment lies within 2r of the
    segment's y at x (clamped to the segment: r·|slope| more at an end), so the rows within 2r
    of it are the candidates, kept where their distance to the segment is ≤ r."""
    n_rows, n_cols = hit.shape
    idx = lambda x: (x + 0.5) * s - 0.5   # noqa: E731  (px → sample index)
    lo = np.maximum(np.ceil(idx(np.minimum(A[:, 0], B[:, 0]) - r)), 0).astype(np.int64)
    hi = np.minimum(np.floor(idx(np.maximum(A[:, 0], B[:, 0]) + r)), n_cols - 1).astype(np.int64)
    count = np.maximum(hi - lo + 1, 0)
    seg = np.repeat(np.arange(len(A)), count)
    col = lo[seg] + np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    a, d, rr = A[seg], (B - A)[seg], r[seg]
    x = (col + 0.5) / s - 0.5
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.clip(np.where(d[:, 0] != 0, (x - a[:, 0]) / d[:, 0], 0.0), 0.0, 1.0)
    y = a[:, 1] + t * d[:, 1]
    first = np.ceil(idx(y - 2 * rr)).astype(np.int64)
    last = np.floor(idx(y + 2 * rr)).astype(np.int64)
    dd = (d * d).sum(-1)
    for k in range(int((last - first).max(initial=-1)) + 1):
        row = first + k
        ok = (row <= last) & (row >= 0) & (row < n_rows)
        py = (row + 0.5) / s - 0.5
        with np.errstate(divide="ignore", invalid="ignore"):
            u = np.clip(np.where(dd > 0, ((x - a[:, 0]) * d[:, 0] + (py - a[:, 1]) * d[:, 1]) / dd, 0.0), 0.0, 1.0)
        near = np.hypot(x - a[:, 0] - u * d[:, 0], py - a[:, 1] - u * d[:, 1]) <= rr
        hit[row[ok & near], col[ok & near]] = True


def units(error: np.ndarray, bound: np.ndarray) -> np.ndarray:
    """``error`` in units of ``bound`` (arrays alike): 0 where both are 0, inf where only the
    bound is (a pixel claimed exact, background both draw, that differs)."""
    error, bound = np.asarray(error, np.float64), np.asarray(bound, np.float64)
    return np.where(bound > 0, error / np.where(bound > 0, bound, 1.0), np.where(error > 0, np.inf, 0.0))


def camera_passes(fx, base: np.ndarray) -> float:
    """The largest |GL − oracle| (full scale) the float32 arithmetic of the camera passes allows
    on the same input image ``base`` with :class:`~glsim.effects.Effects` ``fx`` (M = max |value|
    along the way; u = 2^-24; γ_n ≈ n·u for a sum of n products, Higham §3.1):
    vignette: the gain's rounding, the product's, the oracle's final rounding: 3u·M;
    PSF: per pass the kernel's weights (u), the n products and sums (n·u) over Σ|w|·M = M, and
    the oracle's final rounding: separable (n = 2R + 1, two passes) 2(n + 1)u·M + u·M; 2-D
    (n = (2R + 1)²) (n + 1)u·M + u·M;
    fixed pattern: GLSL's cos is only good to 2^-11 absolute (GLSL 4.50 §8.1), sqrt and our log to
    a few ulps: |Δz| ≤ 5.77·2^-11 + 5.77·8u (|z| ≤ 5.77, the 24-bit bound); times the gain σ·M
    and the offset σ, plus 4u·M for the roundings."""
    u = FLOAT32_ROUNDOFF
    M = float(np.abs(base).max()) * max(float(fx.vignette.max()) if fx.vignette is not None else 1.0, 1.0)
    if fx.fixed_pattern:    # |z| ≤ 5.77
        M = M * (1 + fx.sensor.prnu / 100 * 5.77) + fx.sensor.dsnu / ((1 << fx.bit_depth) - 1) * 5.77
    bound = 0.0
    if fx.vignette is not None:
        bound += 3 * u * M
    if fx.psf is not None:
        n = 2 * fx.psf.radius + 1
        bound += (2 * (n + 1) * u * M if fx.psf.taps is not None else (n * n + 1) * u * M) + u * M
    if fx.fixed_pattern:
        dz = 5.77 * 2.0 ** -11 + 5.77 * 8 * u
        bound += fx.sensor.prnu / 100 * M * dz + fx.sensor.dsnu / ((1 << fx.bit_depth) - 1) * dz + 4 * u * M
    return bound


def phong(X, N, lights, ambient: float, k_r: float, k_s: float, shininess: float, grey=None,
          model: str = "additive") -> np.ndarray:
    """Per point, the largest |I_GL − I| that GLSL 4.50's precision rules (§4.7.1; u = 2^-24,
    1 ULP ≤ 2u) allow shaders/shade.glsl in float32 against glsim.effects.lighting.phong in
    float64 on the same float32 inputs — or, with ``grey``, of combine(grey, I) under ``model`` —
    to first order in u:

    - a normalised vector (N, V, L): the dot product 3u, halved by sqrt, sqrt = 1/inversesqrt
      (2 + 2.5 ULP = 9u): |d|'s relative error ≤ 11u; the division 2.5 ULP: |Δv̂| ≤ 16u;
    - N·L: 2·16u + 3u; R − V = 2(N·L)N − L − V: 2(|Δnl| + |nl|·16u) + 2·16u and the roundings;
      s = |R − V|²/2: |R − V|·|Δ(R − V)| + 3u·s;
    - log(1 − s): for s ≤ ¼ the shader's series, 10u and its 3e-8 relative; else GLSL's log, 2^-21
      absolute on [½, 2), 3 ULP elsewhere; plus |Δs|/(1 − s); x = r·log(1 − s): r times that;
      spec = exp(x): (3 + 2|x|) ULP more;
    - a smooth spot's t = (cos θ − cos_cutoff)/width: (16u + 3u)/width and the division;
      smoothstep's 6t(1 − t) times it; the attenuation I_i/(1 + k d²): 2k d²/(1 + k d²)·11u + 8u;
    - the products and the sum over the lights: one u per term each; float32's smallest normal
      2^-126 absolute where a term underflows.

    Points within reach of a switch (N·V, N·L or R·V crossing 0, a hard spot's edge) are the
    caller's to leave out: there the two may differ by a whole term."""
    from glsim.effects.lighting import geometry

    u = FLOAT32_ROUNDOFF
    unit, len_rel = 16 * u, 11 * u
    g = geometry(X, N, lights, shininess)
    nl, d, lit, spec, cos_theta, spot, att = g.nl, g.d, g.lit, g.spec, g.cos_theta, g.spot, g.att
    sl = np.where(lit, g.s, 0.0)
    lg = np.log1p(-sl)
    dnl = 2 * unit + 3 * u
    dRmV = 2 * (dnl + np.abs(nl) * unit) + 2 * unit + 4 * u * (2 * np.abs(nl) + 2)
    ds = np.sqrt(2 * sl) * dRmV + 3 * u * sl
    dlog = np.where(sl <= 0.25, np.abs(lg) * (10 * u + 3e-8), np.where(1 - sl >= 0.5, 8 * u, 6 * u * np.abs(lg))) \
        + (ds + u * (1 - sl)) / np.maximum(1 - sl, 1e-300)
    x = shininess * lg
    # (+ float32's smallest normal: a value below it may come out as 0)
    dspec = np.where(lit, spec * (shininess * dlog + u * np.abs(x) + (6 + 4 * np.abs(x)) * u) + 2.0 ** -126, 0.0)
    smooth = np.any(lights.dir != 0, axis=-1) & (lights.cos_inner > lights.cos_cutoff)
    width = np.where(smooth, lights.cos_inner - lights.cos_cutoff, 1.0)
    t = np.clip((cos_theta - lights.cos_cutoff) / width, 0.0, 1.0)
    dspot = np.where(smooth, 6 * t * (1 - t) * ((unit + 3 * u) / width + 5 * u * t) + 4 * u, 0.0)
    kd2 = lights.attenuation * d * d
    datt = np.abs(att) * (2 * kd2 / (1 + kd2) * len_rel + 8 * u)
    body = k_r * np.maximum(nl, 0.0) + k_s * spec
    dbody = np.abs(k_r) * dnl * (nl > 0) + np.abs(k_s) * dspec + 2 * u * np.abs(body)
    term = spot * att * body
    dI = np.sum(dspot * np.abs(att * body) + spot * datt * np.abs(body) + spot * np.abs(att) * dbody
                + 3 * u * np.abs(term), axis=-1) + (len(lights.pos) + 1) * u * (abs(ambient) + np.abs(term).sum(-1))
    if grey is None:
        return dI
    I = ambient + term.sum(-1)
    grey = np.asarray(grey, np.float64)
    return (np.abs(grey) * dI + u * np.abs(grey * I)) if model == "multiplicative" else (dI + u * np.abs(grey + I))


def blur(scheme: str, size: np.ndarray, M: float) -> np.ndarray:
    """Per pixel, the largest |GL − mirror| GLSL 4.50's precision rules allow the depth of
    field's float32 gathers (shaders/blur.frag) against their float64 numpy mirrors
    (glsim.effects.dof) on the same float32 source of largest |value| ``M``, ``size`` the
    pixels' σ (Gaussian schemes) or disk radius (px, 0: copied). First order in u:

    - a Gaussian weight e^{x}, x = k²·c, c = −½/σ² from σ in float32 (σ² and the division: 8u,
      the product u): x within 9u|x|, exp's (3 + 2|x|) ULP: ε ≤ (6 + 13|x|)u, |x| ≤ R²/(2σ²);
      weights off by ε move a normalised average of values within M by ≤ 2εM;
    - a 1-D pass of n = 2R + 1 taps: Σ w·v and Σ w (γ_n each), the division 2.5 ULP:
      (2ε + 2n + 5)u·M; the 2-D gather (weights g_x g_y: 2ε; two nested sums and two weight
      sums): (4ε + 4n + 7)u·M; separable: the vertical pass's own plus the largest horizontal
      one (an average passes its input's error on unchanged); hybrid: the larger of the two;
    - a disk weight clamp(r + ½ − |d|, 0, 1): r rounded, |d| = sqrt(dot) (≈ 11u|d|), the
      sums: δw ≤ (14r + 13)u per tap; the average moves by ≤ 2M·Σδw/Σw, plus (2·taps + 5)u·M.
    """
    from glsim.effects.dof import kernel_radius

    u = FLOAT32_ROUNDOFF
    s = np.asarray(size, np.float64)
    H, W = s.shape
    if scheme == "disk":
        R = kernel_radius(s, "disk")
        wsum, dsum, taps = np.zeros(s.shape), np.zeros(s.shape), np.zeros(s.shape)
        for dx, dy, d, inside in _disk_taps(s.shape, int(R.max(initial=0))):
            ok = inside & (abs(dx) <= R) & (abs(dy) <= R)
            wsum += np.where(ok, np.clip(s + 0.5 - d, 0.0, 1.0), 0.0)
            dsum += np.where(ok, (14 * s + 13) * u, 0.0)
            taps += ok
        return np.where(s > 0, 2 * M * dsum / np.where(wsum > 0, wsum, 1.0) + (2 * taps + 5) * u * M, 0.0)
    R = kernel_radius(s)
    n = 2 * R + 1
    eps = (6 + 13 * R ** 2 / (2 * np.where(s > 0, s, 1.0) ** 2)) * u
    pass1d = np.where(s > 0, 2 * eps + (2 * n + 5) * u, 0.0) * M
    gather = np.where(s > 0, 4 * eps + (4 * n + 7) * u, 0.0) * M
    separable = np.where(s > 0, pass1d + pass1d.max(), 0.0)
    return {"gather": gather, "separable": separable, "hybrid": np.maximum(separable, gather)}[scheme]


# per reference interpolant: taps per axis, and the largest Σ|w|, Σ|w'| and Σ|w''| per axis over
# the texel fraction t (glsim.imaging.interp's weights; Keys' cubic has negative lobes: Σ|w| =
# 1.25 at t = ½; linear's w'' is 0 between texels, its gradient jumps across them)
_INTERP = {"linear": (2, 1.0, 2.0, 0.0), "cubic": (4, 1.25, 3.0, 12.0),
           "bspline3": (4, 1.0, 1.5, 4.0), "bspline5": (6, 1.0, 1.2, 2.0)}


def gradient_max(method: str) -> float:
    """The largest |∇I| (per px) of ``method``'s interpolant over coefficients of largest
    |value| 1: each partial derivative is at most Σ|w'|·Σ|w|."""
    _, s0, s1, _ = _INTERP[method]
    return float(np.sqrt(2.0) * s1 * s0)


def hessian(method: str) -> float:
    """The largest Frobenius norm of ``method``'s interpolant's Hessian (per px²) over
    coefficients of largest |value| 1: ∂²/∂u² ≤ Σ|w''|·Σ|w|, ∂²/∂u∂v ≤ (Σ|w'|)²; inf for
    linear, whose gradient jumps between texels (cubic's second derivatives jump but stay
    bounded)."""
    _, s0, s1, s2 = _INTERP[method]
    return float("inf") if method == "linear" else float(np.sqrt(2 * (s2 * s0) ** 2 + 2 * s1 ** 4))


def sample_gradient(method: str, coeffs: np.ndarray, ref_uv: np.ndarray, mask: np.ndarray, s: int = 1) -> np.ndarray:
    """Per pixel (H, W), the largest |∇I| (per px) of ``method``'s interpolant of ``coeffs``
    (:func:`glsim.imaging.interp.prepare`) at the reference points ``ref_uv`` (H·s, W·s, 2) of its
    s×s samples where ``mask`` (H·s, W·s) holds; 0 where none does."""
    from glsim.imaging import interp

    g = np.zeros(mask.shape)
    if mask.any():
        g[mask] = np.linalg.norm(interp.gradient(coeffs, ref_uv[mask], method), axis=-1)
    Hs, Ws = mask.shape
    return g.reshape(Hs // s, s, Ws // s, s).max(axis=(1, 3))


def grey(method: str, coeffs_max: float, gradient, shift, spp: int = 1):
    """The largest |GL − oracle| (full scale) of a pixel of an image without effects, the
    reference image interpolated with ``method`` from coefficients of largest |value| M =
    ``coeffs_max``, where GL and the oracle cover the pixel's samples alike (off the ties,
    :func:`glsim.check.oracle_maps.renderer_ties`) and GL's reference points lie within ``shift`` px of the oracle's,
    at which the interpolant's gradient is at most ``gradient`` (:func:`sample_gradient`;
    numbers or per-pixel arrays). u = 2^-24: a sample's float32 error (:func:`interpolation`)
    and both images' float32 rounding (2uM); at ``spp`` = n > 1 the box filter's n − 1 float32
    adds and its division (2.5 ULP): (n + 4)uM; the points' shift δ: |∇I|·δ + ½·H·δ² (Taylor,
    H = :func:`hessian`·M), or for linear interpolation, whose gradient jumps between texels,
    :func:`gradient_max`·M·δ."""
    u = FLOAT32_ROUNDOFF
    M = float(coeffs_max)
    base = interpolation(method, M) + 2 * u * M + ((spp + 4) * u * M if spp > 1 else 0.0)
    shift = np.asarray(shift, np.float64)
    if method == "linear":
        return base + gradient_max(method) * M * shift
    return base + np.asarray(gradient, np.float64) * shift + 0.5 * hessian(method) * M * shift ** 2


def disk_ramp(r: np.ndarray, dr: np.ndarray) -> np.ndarray:
    """Per pixel (radius ``r`` px, 0: copied; its error ``dr``): the disk gather's |Δout|/δr
    per unit grey range of its window — the taps whose weight clamp(r + ½ − |d|, 0, 1) may
    move with r within ±dr (r − ½ − dr < |d| < r + ½ + dr) over Σw at r, both over the window
    clipped at the image border."""
    from glsim.effects.dof import kernel_radius

    wsum, ramp = np.zeros(r.shape), np.zeros(r.shape)
    for _, _, d, inside in _disk_taps(r.shape, int(kernel_radius(r + dr, "disk").max(initial=0))):
        wsum += np.where(inside, np.clip(r + 0.5 - d, 0.0, 1.0), 0.0)
        ramp += inside & (np.abs(d - r) < 0.5 + dr)
    return np.where(r > 0, ramp / np.where(wsum > 0, wsum, 1.0), 0.0)


def _disk_taps(shape: tuple[int, int], reach: int):
    """Every tap offset (dx, dy) within ``reach`` px (per axis) of the pixels of an image of
    ``shape`` (H, W): with its distance |d| and, per pixel, whether the tap lies in the image."""
    H, W = shape
    yy, xx = np.mgrid[0:H, 0:W]
    for dy in range(-reach, reach + 1):
        for dx in range(-reach, reach + 1):
            yield dx, dy, float(np.hypot(dx, dy)), (yy + dy >= 0) & (yy + dy < H) & (xx + dx >= 0) & (xx + dx < W)


def normal_field(seed: int, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """The noise's standard normal field of ``seed`` over an image of ``shape`` (H, W), as numpy
    makes it (glsim.effects.noise.standard_normal at each flat pixel index), and the bound of
    GLSL's against it per pixel (:func:`standard_normal`)."""
    from glsim.effects import noise as nz

    H, W = shape
    index = np.arange(H * W, dtype=np.uint32).reshape(H, W)
    seed = np.uint32(seed)
    return (nz.standard_normal(index, seed),
            standard_normal(*(nz.uniform01(index, seed, nz.STREAM_U1 + k) for k in (0, 1))))


def interpolation(method: str, coeffs_max: float) -> float:
    """The largest |GL − oracle| of a reference sample (shaders/interp.glsl in float32 against
    glsim.imaging.interp in float64 at the same float64 point), over coefficients (the image, or
    its B-spline coefficients) of largest |value| ``coeffs_max``: with n taps and Σ|w| = S per
    axis, the n² products and sums γ_{n²}·S², each weight's polynomial (≈ 8u, relative, over S²),
    the coefficient texels' float32 rounding (u·S²) and the sample's position rounded to float32
    (u px, times at most 2S·coeffs_max per px): (n² + 9)·u·S²·M + 2u·S·M."""
    n, S = _INTERP[method][:2]
    u = FLOAT32_ROUNDOFF
    return ((n * n + 9) * S * S + 2 * S) * u * coeffs_max


def procedural(dots, shift, glsl: bool = True, float64: bool = True):
    """The largest |GL − oracle| of a procedural reference sample (shaders/procedural.glsl
    against glsim.scene.speckle.evaluate in float64) at points ``shift`` px apart, for the
    speckle ``dots`` (smooth edges, edge_px > 0); ``glsl=False``: the oracle's own float64
    value stored as float32. GLSL 4.50's float32 rules, first order in u = 2^-24, with the
    grid's cell c (max(reach, 1) px rounded up to a float32, glsim.scene.speckle.dot_grid; a dot
    darkens within its reach ≤ c):

    - the offset d = local − centre: local = (g − k)·c rounded (|local| < 2c per axis), the
      dot's centre stored relative to its cell (< c), the difference (< c): |Δd| ≤ √2·5u·c;
      g = (uv − origin)/c is float64 in a float64 build; in a float32 one (``float64=False``)
      the subtraction, division and product add 6u·|uv − origin| per axis, |uv − origin| under
      the reference image's larger side plus the grid's extra cell (max(dots.shape) + c);
    - r = length(d) = 1/inversesqrt(d·d) (2 + 2.5 ULP) over a 3u dot product: 11u·r ≤ 11u·c;
    - x = 0.5 − (r − radius)/edge where 0 < x < 1 (|r − radius| ≤ edge/2): the radius' storage
      (u·c) and the difference's rounding (u·edge/2) over edge, the division (2.5 ULP of a
      quotient ≤ ½), the edge's storage and the subtraction: Δx ≤ (Δr + u·c + u·edge/2)/edge + 5u;
    - the smoothstep x²(3 − 2x), slope ≤ 1.5: 1.5·Δx + 4u; the darkest dot's (max, exact);
    - grey = white − (white − black)·darkness: |white − black|·Δprofile + 6u·max(|white|, |black|)
      (the levels' storage, their difference, the product, the subtraction);
    - the points' distance: the largest slope, |white − black|·1.5/edge, times ``shift`` (px,
      a number or per pixel: then the bound is per pixel)."""
    if not dots.edge_px > 0:
        raise ValueError("procedural: hard dots (edge_px = 0) change grey by a step at their edge")
    u = FLOAT32_ROUNDOFF
    span, level = abs(dots.white - dots.black), max(abs(dots.white), abs(dots.black))
    slope = span * 1.5 / dots.edge_px
    if not glsl:
        return slope * np.asarray(shift) + u * level
    c = max(dots.reach, 1.0)
    dr = np.sqrt(2) * (5 * u * c + (0.0 if float64 else 6 * u * (max(dots.shape) + c))) + 11 * u * c
    dx = (dr + u * c + u * dots.edge_px / 2) / dots.edge_px + 5 * u
    return span * (1.5 * dx + 4 * u) + 6 * u * level + slope * np.asarray(shift)


def f32_error(value: float) -> float:
    """|float32(value) − value|: a float64 uniform's rounding as the shader receives it."""
    return abs(float(np.float32(value)) - float(value))


def coc(Z: np.ndarray, optics) -> np.ndarray:
    """Per depth Z (mm, values float32 holds), the largest relative |GL − numpy| of
    shaders/dof.glsl's coc_px in float32 against glsim.effects.dof.coc_px in float64, both
    f²|Z − D| / (N (Z − f) D) / pitch: the uniforms' rounding to float32 (δ, from their values),
    +, −, × correctly rounded (u each) and each division 2.5 ULP (5u) (GLSL 4.50 §4.7.1), first
    order in u — f² 2δf/f + u; |Z − D| (δD + u|Z − D|)/|Z − D| (the cancellation near focus);
    the product u; N δN/N; Z − f (δf + u|Z − f|)/|Z − f|; the two products 2u; D δD/D; the
    divisions 10u; the pitch δp/p — plus float64's own (10·2^-53)."""
    u = FLOAT32_ROUNDOFF
    Z = np.asarray(Z, np.float64)
    f, N, D, p = (float(getattr(optics, k)) for k in ("focal_length", "f_number", "focus_distance", "pixel_pitch"))
    dZD, dZf = np.abs(Z - D), np.abs(Z - f)
    return (2 * f32_error(f) / f + u + (f32_error(D) + u * dZD) / dZD + u + f32_error(N) / N
            + (f32_error(f) + u * dZf) / dZf + 2 * u + f32_error(D) / D + 10 * u + f32_error(p) / p
            + 10 * 2.0 ** -53)


def standard_normal(u1: np.ndarray, u2: np.ndarray) -> np.ndarray:
    """Per sample, the largest |z_GL − z| of shaders/noise.glsl's standard_normal (float32)
    against glsim.effects.noise.standard_normal (float64) from the same uniforms u1, u2 (bit
    for bit, tested): z = −√(2L)·cos θ, L = −ln u1, θ = 2π(u2 − ½), GLSL 4.50 §4.7.1, first
    order in u:

    - L: log's 3 ULP (6u·L) below u1 = ½; from ½ the shader's series in s = m/(2 − m),
      m = 1 − u1 (exact): s 6u, s² 13u, Horner on s² ≤ 1/9 with float32 coefficients 10u, 2sp 2u:
      18u·L, and the series' cut tail 2s^17/(17(1 − s²)) ≤ 1.2e-9 (s ≤ 1/3);
    - √(2L): sqrt is 1/inversesqrt (2 + 2.5 ULP: 9u) plus half L's relative error;
    - θ: 2π as float32, u2 − ½ and the product (3u·π); cos: absolute 2^-11 on [−π, π] (the
      spec's only guarantee; drivers do far better) plus |sin θ|·δθ;
    - the product: u|z|."""
    u = FLOAT32_ROUNDOFF
    u1, u2 = np.asarray(u1, np.float64), np.asarray(u2, np.float64)
    L = -np.log(u1)
    dL = np.where(u1 < 0.5, 6 * u * L, 18 * u * L + 1.2e-9)
    r = np.sqrt(2 * L)
    theta = 2 * np.pi * (u2 - 0.5)
    dr = r * (0.5 * dL / np.maximum(L, 1e-300) + 9 * u)
    dc = 2.0 ** -11 + np.abs(np.sin(theta)) * 3 * u * np.pi
    return dr * np.abs(np.cos(theta)) + r * dc + u * r


def noise(I: np.ndarray, z: np.ndarray, dz: np.ndarray, sigma: np.ndarray, params, bit_depth: int,
          table=None) -> np.ndarray:
    """Per pixel, the largest |GL − numpy| (full scale) of shaders/noise.frag's I + σ(I)·z
    against glsim.effects.noise.add_noise on the same float32 image I, both rounded to float32:
    ``z`` the numpy normal, ``dz`` its bound (:func:`standard_normal`), ``sigma`` numpy's σ(I).
    σ's float32 error by model — gaussian: its uniform's rounding; heteroscedastic: x = I·dn_max
    (u·x, moving the interpolation by the level table's slope), the variance texels and mix
    (4u of the larger), sqrt (½ the variance's relative error, at most √δv near zero, + 9u) and
    the division (6u); poisson-gaussian: the uniforms (u each), e = I·full_well, e + rn² and the
    sum (3u of it), sqrt and the division (15u) — then σ·dz + |z|·δσ, the product and sum
    (u|σz| + u|I + σz|) and the two float32 roundings (2u|I + σz|)."""
    from glsim.effects import noise as nz

    u = FLOAT32_ROUNDOFF
    I, z, dz, sigma = (np.asarray(a, np.float64) for a in (I, z, dz, sigma))
    model = params.model
    if model == "gaussian":
        dsigma = np.full(I.shape, f32_error(float(sigma.flat[0])))
    elif model == "heteroscedastic":
        dn_max = float((1 << bit_depth) - 1)
        per = nz.variance_per_level(nz._table(params, bit_depth, table), bit_depth)
        slope = np.abs(np.diff(per, append=per[-1]))
        x = np.clip(I * dn_max, 0.0, dn_max)
        n = np.minimum(np.floor(x).astype(np.int64), per.size - 1)
        v = (sigma * dn_max) ** 2
        dv = 4 * u * np.maximum(per[n], per[np.minimum(n + 1, per.size - 1)]) + slope[n] * u * x
        dsigma = (np.minimum(0.5 * dv / np.maximum(v, 1e-300) * sigma * dn_max, np.sqrt(dv)) / dn_max
                  + 15 * u * sigma)
    else:
        fw, rn = float(params.full_well), float(params.read_noise)
        e = np.maximum(I, 0.0) * fw
        rel = ((f32_error(fw) / fw * e + 3 * u * (e + rn * rn) + 2 * f32_error(rn) * abs(rn))
               / np.maximum(e + rn * rn, 1e-300))
        dsigma = sigma * (0.5 * rel + 15 * u + f32_error(fw) / fw)
    out = np.abs(I + sigma * z)
    return sigma * dz + np.abs(z) * dsigma + u * np.abs(sigma * z) + 3 * u * out
