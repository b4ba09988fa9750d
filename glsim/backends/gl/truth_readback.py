"""The truth raster and the view's problem report, read back from a frame's targets: queued when
the frame is submitted (:mod:`glsim.backends.gl.readback`), finished when it is collected."""
from __future__ import annotations

import numpy as np

from glsim.backends.gl.geometry import SHAPE_BYTES
from glsim.backends.gl.rays import ray_bits
from glsim.backends.gl.readback import read_buffer, read_texture
from glsim.imaging import truth
from glsim.imaging.view import warn_dropped, warn_problems


def queue_report(pack, view, s: int, geo, dropped, warn: bool):
    """Copy the view's problem flags, ``dropped`` count and its step's shape filter on the GPU
    (read when the frame is collected), clear them for the next view; returns what warns about
    them (nothing if not ``warn``)."""
    flags, size = geo.status()
    status = read_buffer(pack, [(flags, size), (dropped, 4), (geo.shape_buffer(view), SHAPE_BYTES)]) if warn else None
    geo.clear_status()     # (after the copy above: the GL orders them)
    dropped.write(bytes(4))

    def report():
        if status is None:
            return
        b = status.fetch(pack).tobytes()
        problems = geo.problems(view, b[:size], b[size + 4:])
        if problems:
            warn_problems(view.camera, problems, view.mesh_geo.labels, stacklevel=5)
        warn_dropped(view.camera, int(np.frombuffer(b[size:size + 4], np.uint32)[0]), s)
    return report


def queue_raster(resources, view, mode: str, color, p, patches, polish: bool = True):
    """Queue the truth targets' reads; returns what makes the raster from them: float32 hi
    (+ lo with TRUTH_LO: (ξ, η) to 2^-48) widened to float64, polished where the shader
    computed in float32 and ``polish`` (the patches' (ξ, η) are polished by the caller,
    glsim.render)."""
    W, H = view.camera.size
    pack = resources.pack
    lo = "TRUTH_LO" in p.define_dict
    reads = [read_texture(pack, t, np.float32) for t in color[1:4 if lo else 3]]

    def raster() -> dict:
        m, x, *low = (r.fetch(pack).reshape(H * W, -1) for r in reads)   # each widened once
        out = {"element": np.rint(x[:, 0]).astype(np.int64) - 1, "xi": m[:, 2].astype(np.float64),
               "eta": m[:, 3].astype(np.float64), "ref_uv": m[:, :2].astype(np.float64) + x[:, 1:3]}
        if low:
            out["xi"] += low[0][:, 0]
            out["eta"] += low[0][:, 1]
            return out
        if patches is not None or not polish:
            return out
        return float64_truth(resources, view, mode, out, "FP64" in p.define_dict)
    return raster


def float64_truth(resources, view, mode: str, raster: dict, fp64: bool) -> dict:
    """The raster with float64 (ξ, η) (glsim.imaging.truth.polish) from the float32 ones read
    back, over the covered elements' numpy view only; exact mode polishes on the float64 rays
    the shader used (the ray map, bit for bit) where it has them."""
    hit = raster["element"] >= 0
    if not hit.any():
        return raster
    elements, local = np.unique(raster["element"][hit], return_inverse=True)
    sub = np.full(len(hit), -1, np.int64)
    sub[hit] = local
    xn = ray_bits(resources, view.camera) if mode == "exact" and fp64 else None
    out = truth.polish(view.subset(elements), mode, dict(raster, element=sub), xn)
    out["element"] = raster["element"]
    return out
