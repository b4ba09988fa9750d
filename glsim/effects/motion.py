"""Motion over the exposure and the rolling shutter (docs/motion.md), for either backend.

Times are seconds from the load step's time t_k. A scene's ``[exposure]`` averages the
irradiance over ``time`` T centred on t_k by the midpoint rule: ``samples`` S renders at
τ_i = T·((i + ½)/S − ½), i = 0…S−1, averaged before noise and quantisation. A rolling shutter
(``[sensor] line_time`` L) exposes row r around τ_r = (r − (H − 1)/2)·L (the middle of the frame
at t_k), so row r averages the renders at τ_r + τ_i. Each row is rendered exactly, on its own:
by a camera of one row whose principal point is moved up by r (cy − r), which has the same rays
as row r of the full camera (distortion acts on normalised coordinates); no banding, H·S
renders of one row each.

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
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from glsim.backends.contract import Request
from glsim.effects import prepare as prepare_effects
from glsim.errors import SceneError, check
from glsim.io.images import quantize as quantize_image
from glsim.io.truth import Truth
from glsim.scene.bilinear import bilinear
from glsim.scene.camera import Camera, project_camera_frame, rodrigues, to_camera
from glsim.scene.model import Exposure
from glsim.stages.view import coverage


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
            X = points(self.step)
            if self.omega is not None:
                X = (X - self.centre) @ rodrigues(self.omega * tau).T + self.centre
            return X + self.velocity * tau
        t, ts = self.times[self.step] + tau, self.times
        j = int(np.clip(np.searchsorted(ts, t, side="right") - 1, 0, max(len(ts) - 2, 0)))
        if len(ts) == 1 or t <= ts[j]:
            return points(j)
        if t >= ts[j + 1]:
            return points(j + 1)
        w = (t - ts[j]) / (ts[j + 1] - ts[j])
        return (1 - w) * points(j) + w * points(j + 1)


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
    """The :class:`Timeline` of ``mesh`` (world mm) around ``step``."""
    times = step_times(mesh.step_times, mesh.n_steps, exposure.step_time)
    if not exposure.rigid:
        return Timeline(step, times)
    nodes = mesh.deformed(step)
    centre = np.asarray(exposure.centre if exposure.centre is not None else nodes[np.unique(mesh.quads)].mean(axis=0),
                        np.float64)
    omega = None if exposure.angular_velocity is None else np.asarray(exposure.angular_velocity, np.float64)
    return Timeline(step, times, np.asarray(exposure.velocity or (0.0, 0.0, 0.0), np.float64), omega, centre)


def sample_offsets(duration: float, samples: int) -> np.ndarray:
    """The midpoint rule's instants over an exposure of ``duration`` s centred on 0: (samples,) s."""
    return duration * ((np.arange(samples) + 0.5) / samples - 0.5)


def row_offsets(height: int, line_time: float) -> np.ndarray:
    """Each row's exposure centre (H,) s from the step's time: the middle row at 0."""
    return (np.arange(height) - (height - 1) / 2) * line_time


def row_camera(cam: Camera, row: int) -> Camera:
    """A camera of one row whose pixels are row ``row`` of ``cam`` (same rays)."""
    return dataclasses.replace(cam, size=(cam.width, 1), cy=cam.cy - row)


def render(renderer, camera: int | str, step: int, truth: bool, quantize: bool, jacobian: bool, options: dict):
    """:meth:`glsim.render.Renderer.render` of a scene with ``[exposure]``: a
    :class:`~glsim.render.Result` whose image averages the sub-frames (module text)."""
    from glsim.render import Result

    t0 = time.perf_counter()
    scene, mesh = renderer.scene, renderer.drawn_mesh
    check(not renderer.mesh.is_quadratic, "exposure", "moves meshes of linear elements only; this mesh has "
          "quadratic ones", "remove [exposure], or give a mesh of linear (4-node, 3-node) elements")
    check(not jacobian, "jacobian", "is not made for a scene with [exposure]", "remove [exposure], or jacobian")
    opts = scene.replace(render=options).render if options else scene.render
    renderer.check_size(camera, truth, opts)
    cam = scene.camera(camera)
    line = scene.sensor.line_time if scene.sensor is not None else 0.0
    W, H = cam.size
    rows = [(row_camera(cam, v), tau) for v, tau in enumerate(row_offsets(H, line))] if line > 0 else [(cam, 0.0)]
    tl = timeline(scene.exposure, mesh, step)
    taus = sample_offsets(scene.exposure.time, scene.exposure.samples)
    index = scene.cameras.index(cam)
    frame = _Frames(renderer, tl, index, step, opts)
    images, truths = [], []
    for c, tau_row in rows:
        images.append(sum(frame(c, tau_row + tau, truth and tau == 0).image.astype(np.float64) for tau in taus)
                      / len(taus))
        if truth:
            samples = frame.samples if 0.0 in taus else frame(c, tau_row, True).samples
            truths.append(_row_truth(renderer, c, cam, tl, tau_row, scene.exposure.time, samples))
    image = np.concatenate(images).astype(np.float32)
    stages = tuple(frame.stages)
    fx = frame.effects
    from glsim.effects import noise

    if fx.fixed_pattern:   # as the backends, after the irradiance's stages: on the whole image
        image = noise.fixed_pattern(image, fx.sensor.prnu, fx.sensor.dsnu, fx.bit_depth, fx.fpn_seed).astype(np.float32)
        stages += ("fixed_pattern",)
    if fx.noise is not None:
        image = noise.add_noise(image, fx.noise, fx.bit_depth, fx.noise_seed, fx.variance)
        stages += ("noise",)
    if quantize:
        image = quantize_image(image, cam.bit_depth)
    mid = tl.at(0.0, mesh.deformed)
    specimen = renderer._specimen(cam, mid, mesh.quads) if line == 0 else \
        (lambda: np.concatenate([coverage(c, tl.at(t, mesh.deformed), mesh.quads) for c, t in rows]))
    return Result(image=image, camera=cam, step=step, backend=renderer.backend_name, options=opts,
                  seconds=time.perf_counter() - t0, truth=_stack(truths) if truth else None, stages=stages,
                  specimen=specimen)


class _Frames:
    """Renders the sub-frames of one image: the state at τ through the backend, without temporal
    and fixed-pattern noise (added once to the average); keeps the last frame's effects, stages
    and truth raster."""

    def __init__(self, renderer, tl: Timeline, index: int, step: int, opts):
        self.r, self.tl, self.index, self.step, self.opts = renderer, tl, index, step, opts
        self.samples, self.stages, self.effects = None, (), None

    def __call__(self, cam: Camera, tau: float, truth: bool):
        r, mesh = self.r, self.r.drawn_mesh
        nodes = self.tl.at(tau, mesh.deformed)
        view = r.geometry.view(cam, self.step, None if tau == 0 else float(tau), nodes)
        depths = view.corner_depths() if r.scene.optics is not None else np.empty(0)
        fx = prepare_effects(r.scene, nodes, mesh.quads, cam, self.index, self.step, depths,
                             normals=not r.backend.capabilities.device_geometry)
        self.effects = fx
        out = r.backend.render(Request(view, self.opts, truth, dataclasses.replace(fx, noise=None, sensor=None)))
        self.stages = out.stages
        if truth:
            self.samples = out.samples
        return out


def _row_truth(renderer, cam: Camera, full: Camera, tl: Timeline, tau: float, duration: float,
               samples: dict) -> Truth:
    """Truth of ``cam``'s pixels (a row of ``full``, or itself) at τ (the renderer's maps) with, for
    an exposure of ``duration`` > 0 s, where each pixel's material point is at τ ∓ duration/2
    (``full``'s px)."""
    mesh = renderer.drawn_mesh
    tr = renderer._truth(cam.size, tl.at(tau, mesh.deformed), samples)
    if duration == 0:
        return tr
    e, xi, eta = tr.element[tr.mask], tr.xi[tr.mask], tr.eta[tr.mask]
    ends = []
    for t in (tau - duration / 2, tau + duration / 2):
        X = tl.at(t, lambda k: bilinear(mesh.deformed(k)[mesh.quads[e]], xi, eta))
        uv = np.full(tr.mask.shape + (2,), np.nan)
        uv[tr.mask] = project_camera_frame(to_camera(X, full), full)[0]
        ends.append(uv)
    return dataclasses.replace(tr, uv_start=ends[0], uv_end=ends[1])


def _stack(rows: list[Truth]) -> Truth:
    """One :class:`Truth` of the rows' truths, top to bottom."""
    if len(rows) == 1:
        return rows[0]
    cat = lambda name: np.concatenate([getattr(t, name) for t in rows])   # noqa: E731
    ends = {k: cat(k) for k in ("uv_start", "uv_end") if rows[0].uv_start is not None}
    return Truth(mask=cat("mask"), element=cat("element"), xi=cat("xi"), eta=cat("eta"), ref_uv=cat("ref_uv"),
                 positions=lambda: (cat("X_undeformed"), cat("X_deformed")), **ends)
