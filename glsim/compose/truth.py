"""Truth assembly: what a render's truth is, from the backend's raster of the FE mesh's elements.

A :class:`TruthAssembler` is given to the :class:`glsim.render.Renderer`: :class:`PixelMaps`
(the default) makes the per-pixel :class:`glsim.io.truth.Truth` maps; a library stores only the
covered pixels' (element, ξ, η) (:class:`glsim.workflows.library.worker.CompactAssembler`).
"""
from __future__ import annotations

import functools
from typing import Protocol

import numpy as np

from glsim.effects import motion
from glsim.io.truth import Truth, pixel_positions
from glsim.scene import quadratic as qd
from glsim.scene.bilinear import bilinear
from glsim.scene.camera import Camera, to_camera
from glsim.imaging.quadview import fast_local_coords


class TruthAssembler(Protocol):
    def maps(self, mesh, world: Camera, size: tuple[int, int], deformed: np.ndarray, raster: dict):
        """One frame's truth over ``size`` (W, H) px from a raster of FE ``mesh``'s elements
        (element, ξ, η, ref_uv; flat), its nodes at ``deformed``; ``world``: the camera whose
        frame positions are given in (the scene's first)."""

    def motion_range(self, mesh, tr, cam: Camera, tl: motion.Timeline, tau: float, duration: float):
        """``tr`` (rendered at τ s on ``tl``) with where its material points are over an exposure
        of ``duration`` s."""

    def stack(self, rows: list):
        """A rolling shutter's rows' truths as one, top to bottom."""


class PixelMaps:
    """Truth as per-pixel maps (:class:`glsim.io.truth.Truth`), the positions made on demand."""

    def maps(self, mesh, world: Camera, size, deformed: np.ndarray, raster: dict) -> Truth:
        W, H = size
        elem = raster["element"].reshape(H, W)
        mask = elem >= 0
        xi = np.where(mask, raster["xi"].reshape(H, W), np.nan)
        eta = np.where(mask, raster["eta"].reshape(H, W), np.nan)
        ref = np.where(mask[..., None], raster["ref_uv"].reshape(H, W, 2), np.nan)
        nodes, evaluate = mesh.nodes, functools.partial(material_points, mesh)
        e, x, y = elem[mask], xi[mask], eta[mask]
        return Truth(mask=mask, element=elem, xi=xi, eta=eta, ref_uv=ref,
                     positions=pixel_positions(mask, lambda: (to_camera(evaluate(nodes, e, x, y), world),
                                                              to_camera(evaluate(deformed, e, x, y), world))))

    def motion_range(self, mesh, tr: Truth, cam: Camera, tl: motion.Timeline, tau: float, duration: float) -> Truth:
        """(:func:`glsim.effects.motion.motion_range`: ``uv_start``, ``uv_end``)."""
        return motion.motion_range(tr, mesh, cam, tl, tau, duration, functools.partial(material_points, mesh))

    def stack(self, rows: list[Truth]) -> Truth:
        return motion.stack(rows)


def material_points(mesh, nodes: np.ndarray, elements: np.ndarray, xi, eta) -> np.ndarray:
    """Points (…, 3) mm at (ξ, η) of FE ``mesh``'s ``elements`` with node positions ``nodes``:
    by the patches' own shape functions for quadratic elements, else bilinear."""
    if mesh.is_quadratic:
        return qd.evaluate(qd.patch_points(mesh.patches[elements], nodes), xi, eta)
    return bilinear(nodes[mesh.quads[elements]], xi, eta)


def element_raster(mesh, pieces, ref_cam: Camera, samples: dict, curved: bool) -> dict:
    """The raster of FE ``mesh``'s elements from a backend's ``samples``: a quadratic mesh drawn
    as its pieces (mode fast, not ``curved``) mapped to its patches (:func:`fast_to_patches`)."""
    return fast_to_patches(mesh, pieces, ref_cam, samples) if mesh.is_quadratic and not curved else samples


def fast_to_patches(mesh, pieces, ref_cam: Camera, raster: dict) -> dict:
    """A fast-mode raster of the pieces → the patches: element and (ξ, η) of the parent, then
    (as for linear elements) the material point the reference camera sees at the sample's
    reference point, by Newton on the curved undeformed patch."""
    r = dict(raster)
    hit = np.flatnonzero(r["element"] >= 0)
    piece = r["element"][hit]
    e, xi, eta = pieces.to_parent(piece, r["xi"][hit], r["eta"][hit])
    Pr = qd.patch_points(mesh.patches[e], to_camera(mesh.nodes, ref_cam)) if hit.size else np.zeros((0, 9, 3))
    xi, eta = fast_local_coords(ref_cam, Pr, r["ref_uv"][hit], xi, eta)
    r["element"] = r["element"].copy()
    r["xi"], r["eta"] = r["xi"].copy(), r["eta"].copy()
    r["element"][hit], r["xi"][hit], r["eta"][hit] = e, xi, eta
    return r
