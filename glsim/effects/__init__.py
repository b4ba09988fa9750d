"""The optical effects one render needs, as plain data in the rendering camera's frame.

A scene that names no effect gets ``Effects()`` (all None): the backends then run no
lighting, blur or noise code and compile no such shader.
"""
from __future__ import annotations

import functools
import math
import typing
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from glsim.scene.camera import Camera
from glsim.scene import Lighting, Noise, Optics, Scene, Sensor

if typing.TYPE_CHECKING:
    from glsim.effects.lighting import LightArrays
    from glsim.effects.psf import Kernel as PsfKernel


@dataclass(frozen=True, eq=False)
class Effects:
    """``lights``: camera-frame light arrays; ``normals``: (M, 4, 3) unit corner normals in
    the camera frame; ``noise_seed``: this camera's and step's stream; ``variance``: the
    heteroscedastic table (levels DN, variance DN²); ``sigma_max``: the largest blur σ (or
    disk radius) in px over the view's depth range (0: nothing to blur); ``aperture``,
    ``vignette``, ``psf``, ``sensor`` (fixed-pattern noise): docs/camera.md."""
    lighting: Lighting | None = None
    lights: LightArrays | None = None
    normals: np.ndarray | None = None
    optics: Optics | None = None
    sigma_max: float = 0.0
    noise: Noise | None = None
    noise_seed: int = 0
    variance: tuple | None = None
    bit_depth: int = 8
    aperture: float = 1.0                   # √(sensor.fill_factor): the samples' offsets' scale
    vignette: np.ndarray | None = None      # (H, W) float64 gain (glsim.effects.vignetting)
    psf: PsfKernel | None = None            # the lens PSF (glsim.effects.psf)
    sensor: Sensor | None = None            # for its fixed-pattern noise (prnu, dsnu)
    fpn_seed: int = 0                       # this camera's fixed-pattern stream (not the step's)

    @property
    def blur(self) -> bool:
        return self.optics is not None and self.sigma_max > 0

    @property
    def fixed_pattern(self) -> bool:
        return self.sensor is not None and (self.sensor.prnu > 0 or self.sensor.dsnu > 0)


def corner_normals(nodes: np.ndarray, quads: np.ndarray, cam: Camera, flat: bool) -> np.ndarray:
    """(M, 4, 3) unit normals at each element's corners, camera frame."""
    from glsim.effects import lighting as shade

    if flat:
        n = np.repeat(shade.element_normals(nodes, quads)[:, None], 4, axis=1)
    else:
        n = shade.vertex_normals(nodes, quads)[quads]
    return n @ cam.rotation.T


def max_blur(optics: Optics, depths: np.ndarray) -> float:
    """The largest blur σ (Gaussian) or radius (disk) in px over camera-frame depths (mm)."""
    from glsim.effects import dof as blur

    z = depths[depths > 0]
    if z.size == 0:
        return 0.0
    # the CoC grows monotonically away from the focus plane on either side
    probe = np.array([z.min(), z.max()])
    return float(np.max(blur.blur_sigma(probe, optics)))


def spread(scene: Scene, depths: np.ndarray) -> int:
    """Rows (px) over which the scene's depth of field and lens PSF move light, at camera-frame
    corner depths ``depths`` (mm): a pixel's value depends on the irradiance within this many
    rows of it. Depth of field: each pixel's window, at most dof.kernel_radius of the largest
    blur, + 1 (a pixel's float32 depth may lie an ulp beyond the corners' range, as the GL blur
    allows for); then the PSF's kernel half-width over the blurred rows."""
    rows = 0
    if scene.optics is not None:
        from glsim.effects import dof

        sigma = max_blur(scene.optics, depths)
        rows += int(dof.kernel_radius(sigma, scene.optics.kernel)) + 1 if sigma > 0 else 0
    if scene.psf is not None:
        from glsim.effects.psf import make_kernel

        rows += make_kernel(scene.psf, Path(scene.base_dir)).radius
    return rows


def prepare(scene: Scene, nodes_def: np.ndarray, quads: np.ndarray, cam: Camera, camera_index: int,
            step: int, depths: np.ndarray, normals: bool = True) -> Effects:
    """The :class:`Effects` of ``scene`` for one camera and step (``depths``: element corner
    depths Z in mm, for the blur radius). ``normals`` False leaves out the per-element corner
    normals (the GL path takes them once per load step and rotates them on the GPU)."""
    out: dict = {"bit_depth": cam.bit_depth}
    lit = scene.lighting
    if lit is not None:
        out.update(lighting=lit, lights=_camera_lights(lit, cam),
                   normals=corner_normals(nodes_def, quads, cam, lit.normals == "flat") if normals else None)
    if scene.optics is not None:
        out.update(optics=scene.optics, sigma_max=max_blur(scene.optics, depths))
    nz = scene.noise
    if nz is not None:
        from glsim.effects import noise as noisemod

        out.update(noise=nz, noise_seed=noisemod.stream_seed(scene.seed, camera_index, step))
        if nz.model == "heteroscedastic":
            out["variance"] = noisemod.load_variance_table(scene.resolve(nz.variance_file), cam.bit_depth)
    if scene.sensor is not None:
        from glsim.effects import noise as noisemod

        out.update(aperture=math.sqrt(scene.sensor.fill_factor), sensor=scene.sensor,
                   fpn_seed=noisemod.fixed_pattern_seed(scene.seed, camera_index))
    if scene.vignetting is not None:
        from glsim.effects.vignetting import flat_field

        out["vignette"] = flat_field(cam, scene.vignetting)
    if scene.psf is not None:
        from glsim.effects.psf import make_kernel

        out["psf"] = make_kernel(scene.psf, Path(scene.base_dir))
    return Effects(**out) if len(out) > 1 else _no_effects(cam.bit_depth)


@functools.lru_cache(maxsize=None)
def _no_effects(bit_depth: int) -> Effects:
    """The Effects of a scene that names none (made once per bit depth: they are immutable)."""
    return Effects(bit_depth=bit_depth)


def shading_terms(scene: Scene, nodes: np.ndarray, quads: np.ndarray, cam: Camera, grey, pieces=None):
    """What ``scene``'s lighting adds to ``cam``'s image Jacobian at the deformed ``nodes`` (N, 3,
    world mm) of the drawn ``quads``: :class:`glsim.effects.lighting.ShadingTerms` (``grey(uv)``:
    the reference interpolant's values). ``pieces``: a quadratic mesh's
    :class:`~glsim.scene.quadratic.Pieces` (``nodes``, ``quads``: theirs), whose normals the
    lighting interpolates."""
    from glsim.effects import lighting as shade

    lit, quads = scene.lighting, np.asarray(quads, np.intp)
    flat = lit.normals == "flat"
    source = np.repeat(np.arange(len(quads))[:, None], 4, axis=1) if flat else quads
    return shade.ShadingTerms(lit, _camera_lights(lit, cam), corner_normals(nodes, quads, cam, flat), source, nodes,
                              quads, flat, None if pieces is None else pieces.mesh.grid_matrix(), grey,
                              0 if pieces is None else pieces.n)


def _camera_lights(lit: Lighting, cam: Camera) -> "LightArrays":
    from glsim.effects import lighting as shade

    return shade.lights_to_camera([_light_dict(li) for li in lit.lights], cam.rotation, cam.translation)


def _light_dict(light) -> dict:
    return {"position": light.position, "direction": light.direction, "intensity": light.intensity,
            "attenuation": light.attenuation, "cutoff_deg": light.cutoff, "edge_deg": light.edge}

