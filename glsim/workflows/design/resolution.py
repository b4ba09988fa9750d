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

Strain (a setting with a strain window): pyvale's exx of the same sweep at its strain points, fitted
alike, over the fitted amplitude of the analytic exx at the same points (∂u/∂X = A·(2π/p)·cos(2πX/p),
F = diag(1 + ∂u/∂X, 1), the setting's formulation); the strain's resolution is where that falls to 0.9.

Stereo (engine pyvale3d, :func:`stereo_sweep_row`): the plate sits at the specimen's node centroid
facing the bisector of the two cameras' lines of sight (both cameras foreshorten it alike, as the
DIC Challenge 2.0 stereo set-up; a curved specimen's mean normal could face one camera more than the
other, or away), x along camera 0's x projected onto it; step k moves it along its normal by
W = A·sin(2πx/p_k) (px of camera 0 at the plate's centre). Both cameras render every step, the stereo
engine measures them against step 0 with the design's rig, and the measured displacement's component
along the plate's normal is fitted as U is in 2-D (camera 0's W alone would carry cos of the half
stereo angle). A setting with a strain window adds steps moving the plate along its x (U), whose
pyvale surface exx (tangent t₁ = the plate's x) is fitted against the analytic exx as in 2-D.
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
                   setting.shape_function, max(16, int(math.ceil(2 * amplitude_px)) + 4), strain=setting.strain)
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
            "engine_seconds": np.float64(m.seconds), "engine_version": np.str_(m.version),
            **(strain_sweep(sw, m, setting.strain_formulation) if setting.strain is not None else {})}


# ---- strain (2-D, a setting with a strain window) ------------------------------------------------------
def analytic_strain(x_plate: np.ndarray, period: float, amplitude: float, formulation: str) -> np.ndarray:
    """Exact exx of u = A·sin(2πX/p) (px, X the material point's plate coordinate, px) in pyvale's
    formulation: ∂u/∂X = A·(2π/p)·cos(2πX/p), F = diag(1 + ∂u/∂X, 1), exx of its measure. On the
    fronto-parallel plate the reference image's px are the plate's, so this is what pyvale's
    gradient on the reference image's grid estimates."""
    from glsim.workflows.design.strain import measure

    g = amplitude * (2 * np.pi / period) * np.cos(2 * np.pi * np.asarray(x_plate, float) / period)
    F = np.zeros((len(g), 2, 2))
    F[:, 0, 0], F[:, 1, 1] = 1.0 + np.nan_to_num(g), 1.0
    return np.where(np.isfinite(g), measure(F, formulation)[:, 0, 0], np.nan)


def _motion(sw: Sweep, step: int, x: np.ndarray, y: np.ndarray):
    """The exact image motion (u, v, valid) px at reference pixels (x, y) of ``step``."""
    from glsim.scene.camera import project_camera_frame

    cam = sw.scene.camera(sw.camera)
    uv = np.stack([x, y], axis=1).astype(np.float64)
    t = points_truth(mesh_geometry(sw.mesh), cam, uv, step)
    moved, good = project_camera_frame(to_camera(np.nan_to_num(t.X_deformed), cam), cam)
    ok = t.valid & good
    d = np.where(ok[:, None], moved - uv, np.nan)
    return d[:, 0], d[:, 1], ok


def strain_sweep(sw: Sweep, m, formulation: str) -> dict[str, np.ndarray]:
    """The strain of the sweep per period: pyvale's exx at its strain points fitted as the sinusoid
    (``strain_ratio``: its amplitude over that of the analytic exx fitted at the same points), the
    FE field's own exx likewise (``truth_strain_ratio``: central differences of the rendered field,
    as the design's strain truth), and the period where the ratio falls to 90 %."""
    from glsim.workflows.design import strain as strainmod

    if m.strain_x is None:
        raise GlsimError("the engine returned no strain for the sinusoid sweep (its npz has no strain arrays)")
    xp = truth_at_points(sw, m.strain_x, m.strain_y)
    ratio, truth_ratio, amp = [], [], []
    for k, p in enumerate(sw.periods_px):
        exact = analytic_strain(xp, p, sw.amplitude_px, formulation)
        ref = fit_amplitude(xp, exact, p)
        meas = np.where(m.strain_valid[k], m.exx[k], np.nan)
        fe = strainmod.truth(lambda a, b, k=k: _motion(sw, k + 1, a, b), m.strain_x, m.strain_y,
                             formulation)["truth_exx"]
        amp.append(ref)
        ratio.append(fit_amplitude(xp, meas, p) / ref)
        truth_ratio.append(fit_amplitude(xp, fe, p) / ref)
    ratio = np.array(ratio)
    return {"strain_x": m.strain_x, "strain_y": m.strain_y, "exx": m.exx, "strain_valid": m.strain_valid,
            "strain_x_plate": xp, "strain_amplitude": np.array(amp), "strain_ratio": ratio,
            "truth_strain_ratio": np.array(truth_ratio),
            "strain_spatial_resolution_px": np.float64(spatial_resolution(sw.periods_px, ratio))}


def truth_at_points(sw: Sweep, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The material point's plate x (px from the principal ray) seen at reference pixels (x, y)."""
    cam = sw.scene.camera(sw.camera)
    t = points_truth(mesh_geometry(sw.mesh), cam, np.stack([x, y], axis=1).astype(np.float64), 0)
    xs = to_camera(np.nan_to_num(t.X_undeformed), cam)[:, 0] * cam.fx / sw.depth
    return np.where(t.valid, xs, np.nan)


# ---- stereo (engine pyvale3d): an out-of-plane sinusoid ------------------------------------------------
@dataclasses.dataclass(frozen=True)
class StereoSweep:
    """The stereo sweep's plate: centred on the specimen's node centroid, facing the bisector of the
    two cameras' lines of sight there; load step k moves it along its normal by
    W = A·sin(2πx/p_k), x along camera 0's x projected onto the plate; with ``inplane``, steps
    K + k move it along its x by U = A·sin(2πx/p_k) (K periods). Periods and amplitude in
    camera 0's px at the plate's centre (mm = px·``mm_per_px``). ``axes``: the plate's x, y and
    normal (away from the cameras) as columns, world frame; ``origin``: its centre, world."""
    scene: Scene
    cameras: tuple[str, str]
    mesh: object
    origin: np.ndarray
    axes: np.ndarray
    mm_per_px: float
    periods_px: tuple[float, ...]
    amplitude_px: float
    node_spacing_px: float
    inplane: bool = False


def _centre(cam) -> np.ndarray:
    """A camera's optical centre, world (X_cam = R·X + t)."""
    return -np.asarray(cam.rotation, float).T @ np.asarray(cam.translation, float)


def bisector_axes(cam0, cam1, point: np.ndarray) -> np.ndarray:
    """Columns x, y, z (world): z the normal, away from the cameras along the bisector of the two
    lines of sight to ``point``; x camera 0's x projected onto the plane; y = z × x."""
    sight = [(_centre(c) - point) / np.linalg.norm(_centre(c) - point) for c in (cam0, cam1)]
    b = sight[0] + sight[1]
    if not np.linalg.norm(b) > 1e-9:
        raise GlsimError("the stereo sweep: the cameras look at the specimen from opposite sides — no plate faces both")
    z = -b / np.linalg.norm(b)
    x = np.asarray(cam0.rotation, float)[0]
    x = x - (x @ z) * z
    if not np.linalg.norm(x) > 1e-6:
        raise GlsimError("the stereo sweep: camera 0's x axis is along the bisector — no plate x to vary along")
    x = x / np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z], axis=1)


def _plate_extent(cam, origin: np.ndarray, axes: np.ndarray) -> tuple[float, float]:
    """Half width and height (mm, plate axes) of camera ``cam``'s image corners cast on the plate's plane."""
    W, H = cam.size
    R = np.asarray(cam.rotation, float)
    corners = np.array([[-0.5, -0.5], [W - 0.5, -0.5], [-0.5, H - 0.5], [W - 0.5, H - 0.5]])
    d = np.stack([(corners[:, 0] - cam.cx) / cam.fx, (corners[:, 1] - cam.cy) / cam.fy, np.ones(4)], axis=1) @ R
    C, n = _centre(cam), axes[:, 2]
    s = ((origin - C) @ n) / (d @ n)
    if not np.all(s > 0):
        raise GlsimError("the stereo sweep: camera 0's view does not meet the plate's plane in front of it "
                         "(the plate is seen edge-on) — point the cameras at the specimen")
    local = (C + s[:, None] * d - origin) @ axes
    return float(np.max(np.abs(local[:, 0]))), float(np.max(np.abs(local[:, 1])))


def stereo_sweep_plate(scene: Scene, cameras: tuple[str, str], origin, periods_px, amplitude_px: float,
                       inplane: bool = False) -> StereoSweep:
    """The set-up with the stereo sweep's plate (:class:`StereoSweep`) as its specimen."""
    cam0, cam1 = scene.camera(cameras[0]), scene.camera(cameras[1])
    origin = np.asarray(origin, float)
    axes = bisector_axes(cam0, cam1, origin)
    depth = float(to_camera(origin, cam0)[2])
    if not depth > 0:
        raise GlsimError(f"camera {cameras[0]}: the specimen is behind it (depth {depth:.3g} mm) — point it at the specimen")
    mm = depth / cam0.fx
    hw, hh = (PLATE_COVER * e for e in _plate_extent(cam0, origin, axes))
    spacing_px = min(periods_px) / NODES_PER_PERIOD
    nx = int(math.ceil(2 * hw / (spacing_px * mm)))
    if nx > MAX_NODES_X:
        raise GlsimError(f"resolution.periods_px: a smallest period of {min(periods_px)} px needs {nx} elements "
                         f"across the plate (over {MAX_NODES_X}) — give larger periods")
    width = nx * spacing_px * mm
    ny = max(2, int(math.ceil(2 * hh / (16 * spacing_px * mm))))   # W(x) alone: bilinear is exact in y
    plate = meshmod.plate(width, 2 * hh, nx, ny)
    x = plate.nodes[:, 0] / mm
    steps = []
    for axis in (2, 0) if inplane else (2,):     # W along the normal, then U along the plate's x
        for p in periods_px:
            d = np.zeros_like(plate.nodes)
            d[:, axis] = amplitude_px * mm * np.sin(2 * np.pi * x / p)
            steps.append(d)
    mesh = meshmod.place_mesh(meshmod.with_displacements(plate, steps), "mm", axes, origin)
    spec = dataclasses.replace(scene.specimen, mesh=None, bulge=None, R=tuple(map(tuple, axes)), t=tuple(origin),
                               plate=Plate(width=width, height=2 * hh, nx=nx, ny=ny))
    return StereoSweep(scene.replace(specimen=spec), tuple(cameras), mesh, origin, axes, float(mm),
                       tuple(float(p) for p in periods_px), float(amplitude_px), float(spacing_px), bool(inplane))


def stereo_truth_at(sw: StereoSweep, x: np.ndarray, y: np.ndarray) -> dict[str, np.ndarray]:
    """Per camera-0 subset centre: the material point's plate x (px) and, per period, its exact
    displacement along the plate's normal (mm; with ``inplane`` also along its x, ``truth_u``);
    the plate's normal and x in camera 0's frame."""
    cam = sw.scene.camera(sw.cameras[0])
    R = np.asarray(cam.rotation, float)
    normal, along = R @ sw.axes[:, 2], R @ sw.axes[:, 0]
    g = mesh_geometry(sw.mesh)
    uv = np.stack([x, y], axis=1).astype(np.float64)
    K = len(sw.periods_px)
    xs, ws, us, ok = None, [], [], np.ones(len(x), bool)
    for k in range(1, (2 if sw.inplane else 1) * K + 1):
        t = points_truth(g, cam, uv, k)
        if xs is None:   # camera 0's frame → world → plate
            world = (np.nan_to_num(t.X_undeformed) - np.asarray(cam.translation, float)) @ R
            xs = (world - sw.origin) @ sw.axes[:, 0] / sw.mm_per_px
        ok &= t.valid
        d = np.nan_to_num(t.X_deformed - t.X_undeformed)
        (ws if k <= K else us).append(d @ (normal if k <= K else along))
    out = {"x_plate": np.where(ok, xs, np.nan), "truth_w": np.stack(ws), "truth_valid": ok, "normal": normal,
           "along": along}
    if us:
        out["truth_u"] = np.stack(us)
    return out


def _stereo_points(sw: StereoSweep, step: int, x: np.ndarray, y: np.ndarray):
    """Material points seen at camera-0 pixels: reference position, displacement of ``step``
    (camera 0's frame, mm), valid — the surface strain's truth field."""
    t = points_truth(mesh_geometry(sw.mesh), sw.scene.camera(sw.cameras[0]), np.stack([x, y], axis=1), step)
    return t.X_undeformed, t.X_deformed - t.X_undeformed, t.valid


def stereo_strain_sweep(sw: StereoSweep, m, formulation: str) -> dict[str, np.ndarray]:
    """The in-plane steps' surface strain (pyvale's tangent basis: t₁ camera 0's x projected onto
    the plate, the plate's x): exx fitted per period over the analytic exx of U at the same points
    (``strain_ratio``), the FE field's surface strain likewise (``truth_strain_ratio``)."""
    from glsim.workflows.design import strain as strainmod

    if m.strain_x is None:
        raise GlsimError("the engine returned no strain for the sinusoid sweep (its npz has no strain arrays)")
    K = len(sw.periods_px)
    X0, _, ok = _stereo_points(sw, 1, m.strain_x, m.strain_y)
    cam = sw.scene.camera(sw.cameras[0])
    world = (np.nan_to_num(X0) - np.asarray(cam.translation, float)) @ np.asarray(cam.rotation, float)
    xp = np.where(ok, (world - sw.origin) @ sw.axes[:, 0] / sw.mm_per_px, np.nan)
    ratio, truth_ratio, amp = [], [], []
    for k, p in enumerate(sw.periods_px):
        state = K + k + 1                     # the in-plane steps follow the out-of-plane ones
        ref = fit_amplitude(xp, analytic_strain(xp, p, sw.amplitude_px, formulation), p)
        meas = np.where(m.strain_valid[state], m.exx[state], np.nan)
        fe = strainmod.surface_truth(lambda a, b, s=state: _stereo_points(sw, s, a, b), m.strain_x, m.strain_y,
                                     formulation)["truth_exx"]
        amp.append(ref)
        ratio.append(fit_amplitude(xp, meas, p) / ref)
        truth_ratio.append(fit_amplitude(xp, fe, p) / ref)
    ratio = np.array(ratio)
    return {"strain_x": m.strain_x, "strain_y": m.strain_y, "exx": m.exx[K + 1:], "strain_valid": m.strain_valid[K + 1:],
            "strain_x_plate": xp, "strain_amplitude": np.array(amp), "strain_ratio": ratio,
            "truth_strain_ratio": np.array(truth_ratio),
            "strain_spatial_resolution_px": np.float64(spatial_resolution(sw.periods_px, ratio))}


def stereo_sweep_row(scene: Scene, cameras: tuple[str, str], specimen, setting, noise_seed: int | None, periods_px,
                     amplitude_px: float, eng, folder, margin: int, rig) -> dict[str, np.ndarray]:
    """One stereo resolution row: the out-of-plane sweep rendered by both cameras (noise
    ``noise_seed``), measured by the stereo engine ``eng`` with ``setting`` and the rig ``rig``
    (its calibration), the measured displacement along the plate's normal fitted per period as
    the 2-D sweep fits U, and the truth likewise."""
    from glsim.io.calibfiles import pyvale_calibration
    from glsim.workflows.design import stereo
    from glsim.workflows.design.engine import write_stereo_exchange

    origin = np.mean(np.asarray(specimen.nodes, float), axis=0)
    sw = stereo_sweep_plate(scene, cameras, origin, periods_px, amplitude_px, inplane=setting.strain is not None)
    # the ROI from step 0 and the first period's step, eroded by the amplitude as the 2-D sweep's
    prep = stereo.prepare(sw.scene, sw.cameras, 1, margin + int(math.ceil(amplitude_px)), mesh=sw.mesh)
    K = len(sw.periods_px)
    pairs = stereo.state_pairs(prep, noise_seed, range((2 if sw.inplane else 1) * K + 1))
    write_stereo_exchange(folder / "exchange", pairs, prep.base.roi, pyvale_calibration(*rig), setting.subset_size,
                          setting.subset_step, setting.shape_function, max(16, int(math.ceil(2 * amplitude_px)) + 4),
                          strain=setting.strain)
    m = eng.measure(folder / "exchange")
    if m.X.shape[0] != len(pairs):
        raise GlsimError(f"engine {eng.name}: {m.X.shape[0]} states measured, expected {len(pairs)} (the sweep's)")
    t = stereo_truth_at(sw, m.x, m.y)
    ok = m.valid[1:] & t["truth_valid"][None, :]
    d = np.where(ok[..., None], np.stack([m.U[1:], m.V[1:], m.W[1:]], axis=-1), np.nan)
    w = d[:K] @ t["normal"]
    amp_mm = amplitude_px * sw.mm_per_px
    ratio = np.array([fit_amplitude(t["x_plate"], w[k], p) for k, p in enumerate(sw.periods_px)]) / amp_mm
    truth_ratio = np.array([fit_amplitude(t["x_plate"], t["truth_w"][k], p)
                            for k, p in enumerate(sw.periods_px)]) / amp_mm
    more = {}
    if sw.inplane:   # U along the plate's x, and its surface strain
        u = d[K:] @ t["along"]
        more = {"u_along": u, "truth_u_along": t["truth_u"],
                "inplane_ratio": np.array([fit_amplitude(t["x_plate"], u[k], p)
                                           for k, p in enumerate(sw.periods_px)]) / amp_mm,
                "truth_inplane_ratio": np.array([fit_amplitude(t["x_plate"], t["truth_u"][k], p)
                                                 for k, p in enumerate(sw.periods_px)]) / amp_mm,
                **stereo_strain_sweep(sw, m, setting.strain_formulation)}
        more["inplane_spatial_resolution_px"] = np.float64(spatial_resolution(sw.periods_px, more["inplane_ratio"]))
    return {**more, "x": m.x, "y": m.y, "U": m.U[1:K + 1], "V": m.V[1:K + 1], "W": m.W[1:K + 1], "w_normal": w,
            "valid": m.valid[1:K + 1],
            "x_plate": t["x_plate"], "truth_w": t["truth_w"], "truth_valid": t["truth_valid"],
            "normal": t["normal"], "periods_px": np.array(sw.periods_px), "amplitude_px": np.float64(amplitude_px),
            "amplitude_mm": np.float64(amp_mm), "ratio": ratio, "truth_ratio": truth_ratio,
            "node_spacing_px": np.float64(sw.node_spacing_px), "depth_mm": np.float64(to_camera(sw.origin, scene.camera(cameras[0]))[2]),
            "mm_per_px": np.float64(sw.mm_per_px),
            "spatial_resolution_px": np.float64(spatial_resolution(sw.periods_px, ratio)),
            "engine_seconds": np.float64(m.seconds), "engine_version": np.str_(m.version)}
