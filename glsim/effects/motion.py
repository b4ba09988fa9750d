"""Motion over the exposure and the rolling shutter (docs/motion.md), for either backend: the
times, states and truth; :meth:`glsim.render.Renderer.render` renders and averages the frames.

Times are seconds from the load step's time t_k. A scene's ``[exposure]`` averages the
irradiance over ``time`` T centred on t_k by the midpoint rule: ``samples`` S renders at
τ_i = T·((i + ½)/S − ½), i = 0…S−1, averaged before noise and quantisation. A rolling shutter
(``[sensor] line_time`` L) exposes row r around τ_r = (r − (H − 1)/2)·L (the middle of the frame
at t_k), so row r averages the renders at τ_r + τ_i. Each row is rendered exactly, on its own:
by a camera of one row whose principal point is moved up by r (cy − r), which has the same rays
as row r of the full camera (distortion acts on normalised coordinates); no banding, H·S
renders of one row each. Depth of field and the lens PSF move light across rows: with either,
row r is rendered as the band of rows within their reach (:func:`glsim.effects.spread`, clipped
to the image) in row r's state, blurred as a whole frame is, and cut to row r; H·S renders of
up to 2·spread + 1 rows.

The state at τ (:class:`Timeline`) is affine in the load steps' nodes, so it is evaluated on
nodes (to render) and on material points (truth) alike: a rigid motion of the step's state,
X(τ) = c + R(ωτ)·(X_k − c) + vτ, or the linear interpolation in time between the two load steps
around t_k + τ (held before the first and after the last step).

Truth: each row's mid-exposure state (τ_r: t_k for a global shutter, the same maps as without
motion), and where the exposure has a duration ``uv_start`` / ``uv_end``: where the pixel's
material point is, in the camera's pixels, at the exposure's start and end (τ_r ∓ T/2).
"""
from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from glsim.errors import check
from glsim.io.truth import Truth
from glsim.scene.camera import Camera, project_camera_frame, rodrigues, to_camera
from glsim.scene.optional import Exposure, motion_centre, rigid_state


@dataclass(frozen=True, eq=False)
class Timeline:
    """The specimen's state around load step ``step``: ``times`` (s) of every load step;
    ``velocity`` (mm/s) and ``omega`` (rad/s) about ``centre`` (mm) for a rigid motion, world frame."""
    step: int
    times: np.ndarray
    velocity: np.ndarray | None = None
    omega: np.ndarray | None = None
    centre: np.ndarray | None = None

    @property
    def rigid(self) -> bool:
        return self.velocity is not None

    def at(self, tau: float, points: Callable[[int], np.ndarray]) -> np.ndarray:
        """Points (…, 3) mm at τ s from the step's time; ``points(k)``: the same points at load step k."""
        if tau == 0:
            return points(self.step)
        if self.rigid:
            return rigid_state(points(self.step), tau, self.velocity, self.omega, self.centre)
        (a, wa), *between = self._weights(tau).items()
        if not between:
            return points(a)
        (b, wb), = between
        return wa * points(a) + wb * points(b)

    def _weights(self, tau: float) -> dict[int, float]:
        """The load steps whose states the state at τ interpolates (no rigid motion), and their
        weights: the one before it and the one after, or one held before the first and after the
        last."""
        t, ts = self.times[self.step] + tau, self.times
        j = int(np.clip(np.searchsorted(ts, t, side="right") - 1, 0, max(len(ts) - 2, 0)))
        if len(ts) == 1 or t <= ts[j]:
            return {j: 1.0}
        if t >= ts[j + 1]:
            return {j + 1: 1.0}
        w = (t - ts[j]) / (ts[j + 1] - ts[j])
        return {j: 1 - w, j + 1: w}

    def derivative(self, tau: float) -> np.ndarray:
        """∂X(τ)/∂X_k (3, 3): how the state's points at τ move with their positions at the step
        k itself (its displacements; the other steps, the velocities and the rotation's centre
        held): the rotation R(ωτ) of a rigid motion, the step's weight times I between steps
        (0 where the state is another step's)."""
        if tau == 0 or self.rigid:
            return rodrigues(self.omega * tau) if self.rigid and self.omega is not None else np.eye(3)
        return self._weights(tau).get(self.step, 0.0) * np.eye(3)


def step_times(times: tuple, n_steps: int, step_time: float) -> np.ndarray:
    """The load steps' times (s): the FE file's solver times where every step has one, else
    k·``step_time``; SceneError unless increasing."""
    if times and all(t is not None for t in times):
        ts = np.asarray(times, np.float64)
        check(bool(np.all(np.diff(ts) > 0)), "exposure", f"the load steps' solver times {ts.tolist()} do not "
              "increase, so the state between them is not defined", "select the stored steps in time order")
        return ts
    return np.arange(n_steps, dtype=np.float64) * step_time


def timeline(exposure: Exposure, mesh, step: int) -> Timeline:
    """The :class:`Timeline` of FE ``mesh`` (world mm) around ``step``; the default centre of a
    rotation: the centroid of the nodes its elements use (a quadratic mesh's mid-side and
    centre nodes too)."""
    times = step_times(mesh.step_times, mesh.n_steps, exposure.step_time)
    if not exposure.rigid:
        return Timeline(step, times)
    omega = None if exposure.angular_velocity is None else np.asarray(exposure.angular_velocity, np.float64)
    return Timeline(step, times, np.asarray(exposure.velocity or (0.0, 0.0, 0.0), np.float64), omega,
                    motion_centre(exposure, mesh, step))


def rolling_truth(scene, mesh, step: int) -> dict | None:
    """What a library's truth file keeps of a rolling shutter's rigid motion at ``step`` (FE
    ``mesh``), so that :meth:`glsim.io.truth.CompactTruth.maps` makes each row's positions as the
    renderer does: line_time (s), velocity (mm/s), angular_velocity (rad/s, or None) and the
    rotation's centre as resolved (mm); None without a rolling shutter."""
    if scene.sensor is None or scene.sensor.line_time <= 0:
        return None
    tl = timeline(scene.exposure, mesh, step)
    return {"line_time": scene.sensor.line_time, "velocity": tl.velocity.tolist(),
            "angular_velocity": None if tl.omega is None else tl.omega.tolist(), "centre": tl.centre.tolist()}


def sample_offsets(duration: float, samples: int) -> np.ndarray:
    """The midpoint rule's instants over an exposure of ``duration`` s centred on 0: (samples,) s."""
    return duration * ((np.arange(samples) + 0.5) / samples - 0.5)


def row_band(cam: Camera, row: int, spread: int = 0) -> tuple[Camera, int]:
    """A camera of the rows of ``cam`` within ``spread`` of ``row`` (clipped to its image), whose
    pixels are those rows of ``cam`` (same rays), and ``row``'s index in it. ``spread`` 0: the
    row alone."""
    top, bottom = max(0, row - spread), min(cam.height - 1, row + spread)
    return dataclasses.replace(cam, size=(cam.width, bottom - top + 1), cy=cam.cy - top), row - top


def band_row(raster, at: int, width: int):
    """Row ``at`` of a backend's Raster of a band (:func:`row_band`): its image row and, if it
    has them, its samples (flat over the band's pixels, row-major)."""
    rows = slice(at * width, (at + 1) * width)
    return dataclasses.replace(raster, image=raster.image[at:at + 1],
                               samples=None if raster.samples is None else
                               {k: v[rows] for k, v in raster.samples.items()})


def motion_range(tr: Truth, mesh, cam: Camera, tl: Timeline, tau: float, duration: float, evaluate) -> Truth:
    """``tr`` (pixels of a row of ``cam``, or of ``cam`` itself, rendered at τ s; ``mesh``: the FE
    mesh, whose elements ``tr`` names) with, for an exposure of ``duration`` > 0 s, where each
    pixel's material point is at τ ∓ duration/2 (``cam``'s px: ``uv_start``, ``uv_end``);
    ``evaluate(nodes, elements, ξ, η)``: the elements' points with those node positions."""
    if duration == 0:
        return tr
    e, xi, eta = tr.element[tr.mask], tr.xi[tr.mask], tr.eta[tr.mask]
    ends = []
    for t in (tau - duration / 2, tau + duration / 2):
        X = tl.at(t, lambda k: evaluate(mesh.deformed(k), e, xi, eta))
        uv = np.full(tr.mask.shape + (2,), np.nan)
        uv[tr.mask] = project_camera_frame(to_camera(X, cam), cam)[0]
        ends.append(uv)
    return dataclasses.replace(tr, uv_start=ends[0], uv_end=ends[1])


def stack(rows: list[Truth]) -> Truth:
    """One :class:`Truth` of the rows' truths, top to bottom."""
    if len(rows) == 1:
        return rows[0]
    cat = lambda name: np.concatenate([getattr(t, name) for t in rows])   # noqa: E731
    ends = {k: cat(k) for k in ("uv_start", "uv_end") if rows[0].uv_start is not None}
    return Truth(mask=cat("mask"), element=cat("element"), xi=cat("xi"), eta=cat("eta"), ref_uv=cat("ref_uv"),
                 positions=lambda: (cat("X_undeformed"), cat("X_deformed")), **ends)
