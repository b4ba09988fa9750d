"""Spatial resolution (DIC Challenge 2.0 style): a sinusoidal displacement sweep on a flat plate.

For a set-up, the measured camera looks square onto a flat plate at the specimen's depth (the plate
fills its image); load step k moves the plate's material points by u(x) = A·sin(2πx/p_k) along
the camera's x axis (p_k, A in px at the plate: mm = px·Z/fx). The displacement is the mesh's own
per-node field (Q4 elements, bilinear between nodes), not a warped image: the renderer draws the
moved speckle as for any FE step.

The mesh's node spacing along x is the smallest period / NODES_PER_PERIOD. Bilinear interpolation
of a sinusoid sampled every h keeps sinc²(πh/p) ≈ 1 − (πh/p)²/3 of its amplitude: at 32 nodes per
period 0.32 %, thirty times below the 10 % attenuation that defines the resolution. The truth's own
fitted amplitude (``truth_ratio``, the FE field seen at the subset centres) shows it per period.

The engine measures every step against step 0; at the subset centres the measured U (px) is fitted
by least squares to a·sin(2πx/p) + b·cos(2πx/p) + c, x the material point's plate coordinate
(the period is known, so one period in the image suffices; a period the subset grid aliases — too
few distinct phases — gives NaN; the spec refuses periods ≤ 2 × the subset step);
``ratio`` = √(a² + b²)/A. The spatial resolution is the period at which the ratio falls to 0.9
(log-linear interpolation between the two periods that bracket it); the metrological efficiency
indicator is noise floor × spatial resolution (px²): smaller is better on both axes of the
noise/resolution trade-off. The ratios are measured on the set-up's noisy images (its first noise
seed); the fit over hundreds of subsets averages the noise.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from glsim.errors import GlsimError
from glsim.io.truth import mesh_geometry
from glsim.render import Renderer
from glsim.scene import Scene
from glsim.scene import mesh as meshmod
from glsim.scene.camera import to_camera
from glsim.scene.locate import points_truth
from glsim.scene.model import Plate

NODES_PER_PERIOD = 32
LEVEL = 0.9                  # the DIC Challenge 2.0 threshold: measured / imposed amplitude
PLATE_COVER = 1.15           # the plate's extent over the camera's field of view at its depth
MAX_FIT_CONDITION = 1e3      # the sinusoid fit's design matrix: beyond, the phases are degenerate
MAX_NODES_X = 4000           # a bound on the mesh (periods of a few px over a wide image)


@dataclasses.dataclass(frozen=True)
class Sweep:
    """The sinusoid sweep's plate: its scene (the set-up with this plate as specimen), mesh
    (one load step per period), depth Z (mm), the periods and amplitude (px at the plate)."""
    scene: Scene
    camera: str
    mesh: object
    depth: float
    periods_px: tuple[float, ...]
    amplitude_px: float
    node_spacing_px: float


def specimen_depth(scene: Scene, camera: str, mesh) -> float:
    """Depth (camera frame, mm) of the specimen's node centroid in ``camera``."""
    z = float(np.mean(to_camera(mesh.nodes, scene.camera(camera))[:, 2]))
    if not z > 0:
        raise GlsimError(f"camera {camera}: the specimen is behind it (depth {z:.3g} mm) — point it at the specimen")
    return z


def sweep_plate(scene: Scene, camera: str, depth: float, periods_px, amplitude_px: float) -> Sweep:
    """The set-up with a fronto-parallel plate at ``depth`` and one sinusoid step per period."""
    cam = scene.camera(camera)
    W, H = cam.size
    mm_x, mm_y = depth / cam.fx, depth / cam.fy          # mm per px at the plate
    half_w = PLATE_COVER * max(cam.cx + 0.5, W - 0.5 - cam.cx) * mm_x
    half_h = PLATE_COVER * max(cam.cy + 0.5, H - 0.5 - cam.cy) * mm_y
    spacing_px = min(periods_px) / NODES_PER_PERIOD
    nx = int(math.ceil(2 * half_w / (spacing_px * mm_x)))
    if nx > MAX_NODES_X:
        raise GlsimError(f"resolution.periods_px: a smallest period of {min(periods_px)} px needs {nx} elements "
                         f"across the plate (over {MAX_NODES_X}) — give larger periods")
    width = nx * spacing_px * mm_x                      # whole elements of exactly the spacing
    ny = max(2, int(math.ceil(2 * half_h / (16 * spacing_px * mm_y))))   # u(x) alone: bilinear is exact in y
    # plate frame = camera frame shifted to the principal ray at `depth` (x right, y down in the image)
    R = np.asarray(cam.rotation, float).T
    t = R @ (np.array([0.0, 0.0, depth]) - np.asarray(cam.translation, float))
    plate = meshmod.plate(width, 2 * half_h, nx, ny)
    x = plate.nodes[:, 0] / mm_x                          # px at the plate from the principal ray
    steps = []
    for p in periods_px:
        d = np.zeros_like(plate.nodes)
        d[:, 0] = amplitude_px * mm_x * np.sin(2 * np.pi * x / p)
        steps.append(d)
    mesh = meshmod.place_mesh(meshmod.with_displacements(plate, steps), "mm", R, t)
    spec = dataclasses.replace(scene.specimen, mesh=None, bulge=None, R=tuple(map(tuple, R)), t=tuple(t),
                               plate=Plate(width=width, height=2 * half_h, nx=nx, ny=ny))
    return Sweep(scene.replace(specimen=spec), camera, mesh, depth, tuple(float(p) for p in periods_px),
                 float(amplitude_px), float(spacing_px))


def render_sweep(sw: Sweep, noise_seed: int | None, margin: int) -> tuple[list[np.ndarray], np.ndarray]:
    """[reference, one image per period] (quantised, full scale) with the set-up's noise under
    ``noise_seed`` (None: noise-free), and the ROI (the plate's pixels, eroded)."""
    from scipy import ndimage

    cam = sw.scene.camera(sw.camera)
    full = float(2 ** cam.bit_depth - 1)
    scene = sw.scene if noise_seed is not None else sw.scene.replace(noise=None)
    if noise_seed is not None:
        scene = scene.replace(seed=int(noise_seed))
    images = []
    with Renderer(scene, mesh=sw.mesh) as r:
        first = r.render(sw.camera, 0, quantize=True, truth=True)
        roi = first.truth.mask
        images.append(np.asarray(first.image, np.float64) / full)
        for k in range(1, len(sw.periods_px) + 1):
            images.append(np.asarray(r.render(sw.camera, k, quantize=True).image, np.float64) / full)
    reach = int(math.ceil(sw.amplitude_px)) + margin
    roi = ndimage.binary_erosion(roi, iterations=reach) if reach else roi
    return images, roi


def truth_at(sw: Sweep, x: np.ndarray, y: np.ndarray) -> dict[str, np.ndarray]:
    """Per subset centre: the material point's x at the plate (px from the principal ray), and per
    period the exact truth u (px) of the rendered FE field; (k, n)."""
    from glsim.scene.camera import project_camera_frame

    cam = sw.scene.camera(sw.camera)
    uv = np.stack([x, y], axis=1).astype(np.float64)
    g = mesh_geometry(sw.mesh)
    xs, us, ok = None, [], np.ones(len(x), bool)
    for k in range(1, len(sw.periods_px) + 1):
        t = points_truth(g, cam, uv, k)
        if xs is None:
            xs = to_camera(np.nan_to_num(t.X_undeformed), cam)[:, 0] * cam.fx / sw.depth
        moved, good = project_camera_frame(to_camera(np.nan_to_num(t.X_deformed), cam), cam)
        ok &= t.valid & good
        us.append(moved[:, 0] - uv[:, 0])
    return {"x_plate": np.where(ok, xs, np.nan), "truth_u": np.stack(us), "truth_valid": ok}


def fit_amplitude(x: np.ndarray, u: np.ndarray, period: float) -> float:
    """Least-squares amplitude √(a² + b²) of a·sin(2πx/p) + b·cos(2πx/p) + c through (x, u)."""
    ok = np.isfinite(x) & np.isfinite(u)
    if ok.sum() < 4:
        return math.nan
    ph = 2 * np.pi * x[ok] / period
    A = np.stack([np.sin(ph), np.cos(ph), np.ones_like(ph)], axis=1)
    if np.linalg.cond(A) > MAX_FIT_CONDITION:   # too few distinct phases: centres alias the period
        return math.nan
    a, b, _ = np.linalg.lstsq(A, u[ok], rcond=None)[0]
    return float(math.hypot(a, b))


def spatial_resolution(periods, ratios, level: float = LEVEL) -> float:
    """The period at which ``ratios`` (measured / imposed per period) reaches ``level`` from below:
    log-linear between the largest period under it and the next period at or above it; NaN when
    every ratio is on one side (the sweep does not bracket it)."""
    order = np.argsort(periods)
    p = np.asarray(periods, float)[order]
    r = np.asarray(ratios, float)[order]
    good = np.isfinite(r)
    p, r = p[good], r[good]
    below = np.flatnonzero(r < level)
    if not len(below) or below[-1] == len(p) - 1:
        return math.nan
    i = below[-1]
    f = (level - r[i]) / (r[i + 1] - r[i])
    return float(math.exp(math.log(p[i]) + f * (math.log(p[i + 1]) - math.log(p[i]))))



def sweep_row(scene: Scene, camera: str, specimen, setting, noise_seed: int | None, periods_px, amplitude_px: float,
              eng, folder, margin: int) -> dict[str, np.ndarray]:
    """One resolution row: the sweep rendered (noise ``noise_seed``), measured by ``eng`` with
    ``setting``, the sinusoid fitted per period to the measured U and to the truth."""
    from glsim.workflows.design.engine import write_exchange

    sw = sweep_plate(scene, camera, specimen_depth(scene, camera, specimen), periods_px, amplitude_px)
    images, roi = render_sweep(sw, noise_seed, margin)
    write_exchange(folder / "exchange", images[0], images[1:], roi, setting.subset_size, setting.subset_step,
                   setting.shape_function, max(16, int(math.ceil(2 * amplitude_px)) + 4))
    m = eng.measure(folder / "exchange")
    t = truth_at(sw, m.x, m.y)
    ok = m.valid & t["truth_valid"][None, :]
    u = np.where(ok, m.u, np.nan)
    ratio = np.array([fit_amplitude(t["x_plate"], u[k], p) for k, p in enumerate(sw.periods_px)]) / amplitude_px
    truth_ratio = np.array([fit_amplitude(t["x_plate"], t["truth_u"][k], p)
                            for k, p in enumerate(sw.periods_px)]) / amplitude_px
    return {"x": m.x, "y": m.y, "u": m.u, "v": m.v, "valid": m.valid, "x_plate": t["x_plate"],
            "truth_u": t["truth_u"], "truth_valid": t["truth_valid"], "periods_px": np.array(sw.periods_px),
            "amplitude_px": np.float64(amplitude_px), "ratio": ratio, "truth_ratio": truth_ratio,
            "node_spacing_px": np.float64(sw.node_spacing_px), "depth_mm": np.float64(sw.depth),
            "mm_per_px": np.float64(sw.depth / sw.scene.camera(camera).fx),
            "spatial_resolution_px": np.float64(spatial_resolution(sw.periods_px, ratio)),
            "engine_seconds": np.float64(m.seconds), "engine_version": np.str_(m.version)}
