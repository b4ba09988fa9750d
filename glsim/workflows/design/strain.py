"""Strain in a design (engine pyvale2d, ``[dic] strain_window``): the exact in-plane strain at the
engine's strain points, and the strain bias and noise maps and figures of one set-up × setting.

The truth is the strain of the displacement field the 2-D DIC measures: d(x) = (u, v)(x), px, the
image motion of the material point seen at reference pixel x (its FE displacement of ``step``,
projected into the camera), as a function of the reference image's pixel coordinates. Its gradient
∇d (px/px) by central differences of ±``DELTA`` px of that exact field (exact for a field affine
across the stencil), F = I + ∇d, and pyvale's measure of F (as pyvale.strain computes it)::

    GREEN          E = ½ (FᵀF − I)
    ALMANSI        e = ½ (I − (FFᵀ)⁻¹)
    HENCKY         H = ½ ln(FᵀF)           (through the eigen-decomposition of FᵀF)
    BIOT_LAGRANGE  U − I,  U = √(FᵀF)
    BIOT_EULER     V − I,  V = √(FFᵀ)

components xx, yy and the tensor shear xy. For a plate square onto the camera (image axes along
the plate's, constant depth) the image's ∇d is the plate's in-plane ∇u: the material strain.

Stereo (engine pyvale3d): pyvale's surface strain. At a strain point (camera 0's reference pixel)
the material point X₀ seen there and those seen ±``DELTA`` px away (camera 0's frame, mm, with
their displacements U of ``step``); the surface's normal n from the cross product of the two
chords (towards +z, as pyvale), the tangent basis t₁ = camera 0's x projected onto the surface, t₂
= n × t₁ (pyvale's); ∂U/∂s (3 × 2) in the tangent coordinates s from the chords, and F = I + Bᵀ·[∂U/∂s₁
∂U/∂s₂ 0] with B = [t₁ t₂ n] (pyvale's ``compute_surface_F_3d``); the same measure of the 3 × 3 F.
"""
from __future__ import annotations

import math

import numpy as np

from glsim.workflows.design.stats import common_points, median, pct, rms

DELTA = 0.5        # px: the truth gradient's central-difference half step
COMPONENTS = ("exx", "eyy", "exy")


def _sym_fn(C: np.ndarray, fn) -> np.ndarray:
    """fn applied to the eigenvalues of symmetric matrices C (n, k, k)."""
    w, Q = np.linalg.eigh(C)
    return np.einsum("nij,nj,nkj->nik", Q, fn(w), Q)


def measure(F: np.ndarray, formulation: str) -> np.ndarray:
    """Strain tensors (n, k, k) of deformation gradients F (n, k, k) in pyvale's formulation; k = 2
    for the 2-D engine (F's out-of-plane row and column those of the identity, as pyvale's 2-D F),
    3 for the surface's F."""
    eye = np.eye(F.shape[-1])
    Ft = np.transpose(F, (0, 2, 1))
    if formulation == "GREEN":
        return 0.5 * (Ft @ F - eye)
    if formulation == "ALMANSI":
        return 0.5 * (eye - np.linalg.inv(F @ Ft))
    if formulation == "HENCKY":
        return 0.5 * _sym_fn(Ft @ F, np.log)
    if formulation == "BIOT_LAGRANGE":
        return _sym_fn(Ft @ F, np.sqrt) - eye
    if formulation == "BIOT_EULER":
        return _sym_fn(F @ Ft, np.sqrt) - eye
    raise ValueError(f"strain formulation {formulation!r} is not one of pyvale's")


def truth(displacement, x: np.ndarray, y: np.ndarray, formulation: str) -> dict[str, np.ndarray]:
    """The exact strain at points (x, y) px; ``displacement(x, y)`` → (u, v, valid) px is the exact
    image-motion field (planar.truth_px). NaN where a stencil point sees no specimen."""
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    n = len(x)
    px, py = np.concatenate([x + DELTA, x - DELTA, x, x]), np.concatenate([y, y, y + DELTA, y - DELTA])
    u, v, ok = displacement(px, py)
    u, v, ok = (np.asarray(a).reshape(4, n) for a in (u, v, ok))
    grad = np.empty((n, 2, 2))
    grad[:, 0, 0] = (u[0] - u[1]) / (2 * DELTA)
    grad[:, 0, 1] = (u[2] - u[3]) / (2 * DELTA)
    grad[:, 1, 0] = (v[0] - v[1]) / (2 * DELTA)
    grad[:, 1, 1] = (v[2] - v[3]) / (2 * DELTA)
    valid = ok.all(axis=0) & np.isfinite(grad).all(axis=(1, 2))
    grad[~valid] = 0.0
    return _components(measure(np.eye(2) + grad, formulation), valid)


def _components(eps: np.ndarray, valid: np.ndarray) -> dict[str, np.ndarray]:
    out = {f"truth_{c}": np.where(valid, eps[:, i, j], np.nan)
           for c, (i, j) in zip(COMPONENTS, ((0, 0), (1, 1), (0, 1)))}
    return {**out, "truth_strain_valid": valid}


def surface_truth(points, x: np.ndarray, y: np.ndarray, formulation: str) -> dict[str, np.ndarray]:
    """The exact surface strain at camera-0 pixels (x, y) in pyvale's tangent basis (module doc);
    ``points(x, y)`` → (X (n, 3) reference position, U (n, 3) displacement, valid), camera 0's frame."""
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    n = len(x)
    px, py = np.concatenate([x + DELTA, x - DELTA, x, x]), np.concatenate([y, y, y + DELTA, y - DELTA])
    X, U, ok = points(px, py)
    X, U, ok = np.asarray(X).reshape(4, n, 3), np.asarray(U).reshape(4, n, 3), np.asarray(ok).reshape(4, n)
    valid = ok.all(axis=0)
    X, U = np.where(valid[None, :, None], X, 0.0), np.where(valid[None, :, None], U, 0.0)
    dXa, dXb = X[0] - X[1], X[2] - X[3]          # the chords along the pixel's x and y
    normal = np.cross(dXa, dXb)
    length = np.linalg.norm(normal, axis=1)
    valid &= length > 0
    normal = normal / np.where(length > 0, length, 1.0)[:, None]
    normal *= np.where(normal[:, 2] < 0, -1.0, 1.0)[:, None]
    t1 = np.array([1.0, 0.0, 0.0]) - normal * normal[:, :1]
    n1 = np.linalg.norm(t1, axis=1)
    valid &= n1 > math.sin(math.radians(0.1))      # pyvale's limit (its z fallback is not modelled)
    t1 = t1 / np.where(n1 > 0, n1, 1.0)[:, None]
    t2 = np.cross(normal, t1)
    B = np.stack([t1, t2, normal], axis=2)          # columns t1, t2, n
    S = np.stack([np.einsum("nk,nkj->nj", dXa, B[:, :, :2]), np.einsum("nk,nkj->nj", dXb, B[:, :, :2])], axis=2)
    dU = np.stack([U[0] - U[1], U[2] - U[3]], axis=2)           # (n, 3, 2): U along the two chords
    det = np.linalg.det(S)
    valid &= np.abs(det) > 0
    S[~valid] = np.eye(2)
    grad = dU @ np.linalg.inv(S)                                # ∂U/∂s, (n, 3, 2)
    G = np.zeros((n, 3, 3))
    G[:, :, :2] = grad
    F = np.eye(3) + np.transpose(B, (0, 2, 1)) @ G
    F[~valid] = np.eye(3)
    return _components(measure(F, formulation), valid)


def row_arrays(m, truth_fn, formulation: str, static: int = 0, deformed: int = 1) -> dict[str, np.ndarray]:
    """An engine row's strain arrays from the engine's results ``m`` (states ``static`` and
    ``deformed``) with the truth ``truth_fn(x, y, formulation)`` at its strain points."""
    if m.strain_x is None:
        raise ValueError("the engine returned no strain (its npz has no strain arrays)")
    out = {"strain_x": m.strain_x, "strain_y": m.strain_y, "static_strain_valid": m.strain_valid[static],
           "strain_valid": m.strain_valid[deformed]}
    for c in COMPONENTS:
        out[f"static_{c}"], out[c] = getattr(m, c)[static], getattr(m, c)[deformed]
    return {**out, **truth_fn(m.strain_x, m.strain_y, formulation)}


def _stack(rows: list[dict]) -> dict:
    """Strain arrays of one (set-up, setting)'s engine rows on their common strain points."""
    x, y, idx = common_points([r["strain_x"] for r in rows], [r["strain_y"] for r in rows])
    names = [*COMPONENTS, *(f"static_{c}" for c in COMPONENTS), *(f"truth_{c}" for c in COMPONENTS),
             "strain_valid", "static_strain_valid", "truth_strain_valid"]
    return {"x": x, "y": y, **{k: np.stack([r[k][i] for r, i in zip(rows, idx)]) for k in names}}


def _finite(a: np.ndarray) -> np.ndarray:
    return a[np.isfinite(a)]


def aggregate(rows: list[dict]) -> tuple[dict, dict]:
    """Figures and maps of one (set-up, setting)'s engine rows with strain: per strain point the
    bias (mean over realisations − truth) and noise (std over realisations, ddof = 1) of each
    component; ``rms_strain_bias`` (RMS over points and components of the bias),
    ``median_strain_noise`` (median over points of the components' RMS noise),
    ``p95_abs_strain_error`` (95th percentile over points, realisations and components of
    |strain − truth|), ``strain_noise_floor`` (the static pair's: per component the std over
    points and realisations, their RMS; its truth is 0)."""
    st = _stack(rows)
    ok = st["strain_valid"] & st["truth_strain_valid"]
    n_ok = ok.sum(axis=0)
    summary, maps = {}, {"strain_x": st["x"], "strain_y": st["y"]}
    errs, biases, noises, floors = [], [], [], []
    for c in COMPONENTS:
        e = np.where(ok, st[c] - st[f"truth_{c}"], np.nan)
        with np.errstate(invalid="ignore", divide="ignore"):
            bias = np.where(n_ok > 0, np.nansum(e, 0) / n_ok, np.nan)
            noise = np.sqrt(np.nansum((e - bias) ** 2, 0) / (n_ok - 1))
        noise[n_ok < 2] = np.nan
        s = st[f"static_{c}"][st["static_strain_valid"]]
        s = _finite(s)
        floor = float(np.std(s)) if s.size else math.nan
        summary[f"strain_noise_floor_{c}"] = floor
        summary[f"strain_bias_mean_{c}"] = float(np.mean(_finite(bias))) if _finite(bias).size else math.nan
        maps[f"strain_bias_{c}"], maps[f"strain_noise_{c}"] = bias, noise
        errs.append(_finite(np.abs(e)))
        biases.append(bias)
        noises.append(noise)
        floors.append(floor)
    err = np.concatenate(errs)
    b = np.concatenate(biases)
    noise_rms = np.sqrt(np.mean(np.square(noises), axis=0))
    summary.update(strain_points=len(st["x"]), strain_valid_share=float(np.mean(st["strain_valid"])),
                   p95_abs_strain_error=pct(err), rms_strain_bias=rms(b), median_strain_noise=median(noise_rms),
                   strain_noise_floor=float(math.sqrt(np.mean(np.square(floors)))))
    return summary, maps


def row_summary(r: dict) -> dict:
    """One engine row's strain figures (the rows CSV)."""
    ok = r["strain_valid"] & r["truth_strain_valid"]
    e = np.concatenate([np.abs(r[c] - r[f"truth_{c}"])[ok] for c in COMPONENTS])
    s = r["static_strain_valid"]
    return {"strain_points": len(r["strain_x"]),
            "p95_abs_strain_error": float(np.percentile(e, 95)) if e.size else math.nan,
            "static_std_exx": float(np.std(r["static_exx"][s])) if s.any() else math.nan}
