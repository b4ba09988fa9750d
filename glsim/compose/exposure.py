"""An exposure's image (docs/motion.md; the times and states: :mod:`glsim.effects.motion`): per
row of a rolling shutter (else once) the mean of its sub-frames' renders, then fixed-pattern and
temporal noise on the whole image; its truth (each row's mid-exposure state) and its Jacobian
(the mean of the sub-frames', each chained through its state's derivative).

Depth of field and the lens PSF move light between rows, so with either a rolling shutter's row
is rendered as the band of rows within their reach (:func:`glsim.effects.spread`) and cut to it.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np
from scipy import sparse

from glsim.backends.contract import Request
from glsim.compose import chain
from glsim.compose.drawing import Drawing
from glsim.compose.truth import TruthAssembler, element_raster
from glsim.effects import motion, noise as noisemod, spread as spread_rows
from glsim.errors import SceneError
from glsim.scene import Render, Scene
from glsim.scene.camera import Camera
from glsim.scene.optional import row_offsets
from glsim.imaging.view import coverage


@dataclass(frozen=True, eq=False)
class Exposed:
    """An exposure's image, float32 (H, W) with its noise, and what the Result takes with it;
    ``specimen``: a rolling shutter's pixel mask, each row in its own state (None: the frame's)."""
    image: np.ndarray
    stages: tuple[str, ...]
    truth: object | None = None
    specimen: Callable[[], np.ndarray] | None = None
    jacobian: object | None = None
    rig_jacobian: object | None = None


def schedule(scene: Scene, mesh, cam: Camera, step: int):
    """The sub-frames that make ``cam``'s image at ``step`` under ``scene``'s [exposure] (FE
    ``mesh``): the rows of a rolling shutter, each with its exposure centre (s from the step's
    time; [(None, 0.0)]: the whole frame at once), the step's :class:`~glsim.effects.motion.Timeline`
    and the midpoint rule's offsets τ_i (s); each row's image is the mean of its renders at
    centre + τ_i."""
    ex, sensor = scene.exposure, scene.sensor
    if ex is None:
        raise SceneError("exposure", "the scene has no [exposure] table, so each image is one render",
                         "add [exposure] (time, samples, velocity …) to average sub-frames")
    line = sensor.line_time if sensor is not None else 0.0
    rows = list(enumerate(row_offsets(cam.height, line))) if line > 0 else [(None, 0.0)]
    return rows, motion.timeline(ex, mesh, step), motion.sample_offsets(ex.time, ex.samples)


def sub_frames(d: Drawing, cam: Camera, step: int, opts: Render, truth: bool) -> Iterator[tuple]:
    """The renders :func:`expose` averages, in :func:`schedule`'s order (rows, then τ_i): (row or
    None, τ s from the step's time, the state's nodes (world mm, of the mesh drawn), the Raster —
    the row's, cut from its band — without noise; ``truth``: with its samples)."""
    rows, tl, taus = schedule(d.scene, d.mesh, cam, step)
    for row, t in rows:
        for tau in taus:
            yield row, t + tau, tl.at(t + tau, d.drawn_mesh.deformed), frame(d, cam, step, t + tau, tl, opts, truth,
                                                                             row)[0]


def expose(d: Drawing, cam: Camera, step: int, opts: Render, truth: bool, jacobian: bool, rig: bool,
           assembler: TruthAssembler) -> Exposed:
    """``cam``'s image at ``step`` under the scene's [exposure]; ``truth`` by ``assembler``;
    ``jacobian``: the mean of the sub-frames' Jacobians (``rig``: with the rig Jacobian)."""
    scene, mesh = d.scene, d.drawn_mesh
    rows, tl, taus = schedule(scene, d.mesh, cam, step)
    rolling = rows[0][0] is not None
    one = opts.supersampling == 1   # (a sub-frame's own raster is its samples')
    images, truths, jacobians = [], [], []
    for row, t in rows:
        frames = [frame(d, cam, step, t + tau, tl, opts, (truth and tau == 0) or (jacobian and one), row)
                  for tau in taus]
        images.append(sum(out.image.astype(np.float64) for out, _ in frames) / len(taus))
        if jacobian:
            Js, rigs = zip(*(sub_jacobian(d, cam, step, opts, out.samples if one else None, rig, tl, t + tau, row)
                             for (out, _), tau in zip(frames, taus)))
            jacobians.append((sum(Js) / len(taus), sum(rigs) / len(taus) if rig else None))
        if truth:
            out = next((out for (out, _), tau in zip(frames, taus) if tau == 0), None) or \
                frame(d, cam, step, t, tl, opts, True, row)[0]
            curved = d.mesh.is_quadratic and opts.mode != "fast"
            raster = element_raster(d.mesh, d.pieces, d.reference.camera, out.samples, curved)
            tr = assembler.maps(d.mesh, scene.cameras[0], out.image.shape[::-1], tl.at(t, d.mesh.deformed), raster)
            truths.append(assembler.motion_range(d.mesh, tr, cam, tl, t, scene.exposure.time))
    (out, fx), image = frames[-1], np.concatenate(images).astype(np.float32)
    stages = tuple(out.stages)
    if fx.fixed_pattern:   # as the backends do, on the whole image
        image = noisemod.fixed_pattern(image, fx.sensor.prnu, fx.sensor.dsnu, fx.bit_depth,
                                       fx.fpn_seed).astype(np.float32)
        stages += ("fixed_pattern",)
    if fx.noise is not None:
        image = noisemod.add_noise(image, fx.noise, fx.bit_depth, fx.noise_seed, fx.variance)
        stages += ("noise",)
    specimen = None
    if rolling:   # each row's own state
        specimen = lambda: np.concatenate([coverage(motion.row_band(cam, row)[0], tl.at(t, mesh.deformed),  # noqa: E731
                                                    mesh.quads) for row, t in rows])
    derivatives = {}
    if jacobian:
        J = sparse.csr_matrix(sparse.vstack([j for j, _ in jacobians]))
        J_rig = sparse.csr_matrix(sparse.vstack([r for _, r in jacobians])) if rig else None
        gain_term = None if rolling and banded(scene) else \
            chain.gain_term(d, cam, step, opts, rig, tl, taus, rows if rolling else None)   # (banded: per band)
        derivatives = chain.through_camera(d, cam, J, J_rig, ("prnu",) if rolling and banded(scene) else None,
                                           gain_term)
    return Exposed(image, stages, assembler.stack(truths) if truth else None, specimen, **derivatives)


def banded(scene: Scene) -> bool:
    """Whether a rolling shutter's rows are rendered as bands (:func:`frame`): the depth of
    field or the PSF move light between rows."""
    return scene.optics is not None or scene.psf is not None


def row_band(d: Drawing, cam: Camera, step: int, state, nodes: np.ndarray, row: int):
    """A rolling shutter's ``row`` as the band of rows whose light the depth of field and the
    PSF move into it at this state's depths (:func:`glsim.effects.spread`): the band's camera,
    the row's index in it, and the corner depths (mm; empty without [optics])."""
    view = d.geometry.view(cam, step, state, nodes)
    depths = view.corner_depths() if d.scene.optics is not None else np.empty(0)
    return (*motion.row_band(cam, row, spread_rows(d.scene, depths)), depths)


def frame(d: Drawing, cam: Camera, step: int, tau: float, tl: motion.Timeline, opts: Render, truth: bool,
          row: int | None = None):
    """One sub-frame: the state τ s from ``step``'s time, rendered without temporal and
    fixed-pattern noise; (Raster, the Effects). ``row``: only that row of ``cam`` (a rolling
    shutter's), rendered as the band of rows whose light the depth of field and the PSF move
    into it (:func:`glsim.effects.spread`) and cut to it."""
    state = None if tau == 0 else float(tau)
    nodes = tl.at(tau, d.drawn_mesh.deformed)
    curved = d.curved(opts, step, tl, tau)
    if row is None:
        view = d.geometry.view(cam, step, state, nodes)
        depths = view.corner_depths() if d.scene.optics is not None else np.empty(0)
    else:
        cam, at, depths = row_band(d, cam, step, state, nodes, row)
        view = d.geometry.view(cam, step, state, nodes)
    fx = d.effects(cam, step, nodes, depths)   # (a band camera's index: its camera's, by name)
    out = d.render(Request(view, opts, truth, dataclasses.replace(fx, noise=None, sensor=None), curved))
    return (out if row is None else motion.band_row(out, at, cam.width)), fx


def sub_jacobian(d: Drawing, cam: Camera, step: int, opts: Render, raster: dict | None, rig: bool,
                 tl: motion.Timeline, tau: float, row: int | None):
    """One sub-frame's (J, J_rig) in :func:`expose`: of ``cam``, or of a rolling shutter's
    ``row`` — the row's one-row camera with its own ``raster``, or, where the rows are banded,
    the band's Jacobian (its raster rendered), through its depth of field, vignetting and PSF as
    the band is rendered, cut to the row."""
    if row is None or not banded(d.scene):
        return chain.raster_jacobian(d, cam if row is None else motion.row_band(cam, row)[0], step, opts, raster, rig,
                                     tl, tau)
    band, at, _ = row_band(d, cam, step, None if tau == 0 else float(tau), tl.at(tau, d.drawn_mesh.deformed), row)
    J, J_rig = chain.raster_jacobian(d, band, step, opts, None, rig, tl, tau)
    rows = slice(at * cam.width, (at + 1) * cam.width)
    out = chain.through_camera(d, band, J, J_rig, ("vignetting", "psf"), chain.gain_term(d, band, step, opts, rig, tl,
                                                                                         (tau,)))
    return out["jacobian"][rows], None if J_rig is None else out["rig_jacobian"][rows]
