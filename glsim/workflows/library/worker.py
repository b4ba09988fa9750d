"""The worker side of a library: render a task (some images of one variant) and write its files.

A task is plain data (the variant's resolved scene as JSON, the images, the output directory)
so that it runs the same in this process, in a local process pool or on a Dask worker. Each
worker thread holds one GL context, made when its first task runs, and one
:class:`~glsim.render.Renderer`, reused for the next variant when that shares the mesh,
reference image and backend (only the scene's options change); otherwise the old renderer's
GL resources are released and a new one made on the same context. A GL context is current on
one thread, so the context and renderer are per thread (``threading.local``).

Encoding (quantising, TIFF/PNG, compact truth), hashing and writing run in a writer process
(:mod:`.writer`, one per worker thread, kept) while the next image renders. Every image and
its truth are written as one group under temporary names and renamed truth first, image last
(:func:`glsim.io.images.atomic_paths`): a task killed at any moment leaves no truncated file
under a final name, and a task run twice (a Dask worker that died and its task rerun
elsewhere) writes the same bytes again.
"""
from __future__ import annotations

import contextlib

import os
import threading
from pathlib import Path

import numpy as np

from glsim.effects import motion
from glsim.errors import GlsimError
from glsim.limits import keep
from glsim.io import truth as truthio, truthcodec
from glsim.render import Renderer

_LOCAL = threading.local()


class CompactRaster:
    """The truth a library stores (:func:`glsim.io.truth.compact`): ``element`` (H, W) int32,
    ``xi``/``eta`` (n,) float64 of the n covered pixels in raster order."""

    def __init__(self, element, xi, eta):
        self.element, self.xi, self.eta = element, xi, eta


class CompactAssembler:
    """The library's truth (:class:`glsim.compose.truth.TruthAssembler`): only the compact
    (element, ξ, η); no float64 map of the positions or reference coordinates is made (the truth
    file determines them), and the backend's full-size raster is dropped as soon as the covered
    pixels are gathered."""

    def maps(self, mesh, world, size, deformed, raster) -> CompactRaster:
        W, H = size
        return CompactRaster(*truthcodec.compact(raster["element"].reshape(H, W), raster["xi"], raster["eta"]))

    def motion_range(self, mesh, tr, cam, tl, tau, duration) -> CompactRaster:
        """A library's truth is the mid-exposure state's (a global shutter's: the load step's;
        a rolling shutter's rows': glsim.io.truth.CompactTruth.maps); its files hold no motion
        range."""
        return tr

    def stack(self, rows: list[CompactRaster]) -> CompactRaster:
        """A rolling shutter's rows, top to bottom (their covered pixels in raster order)."""
        return CompactRaster(np.concatenate([t.element for t in rows]), np.concatenate([t.xi for t in rows]),
                             np.concatenate([t.eta for t in rows]))


def _scene(scene_json: str):
    import json

    from glsim.scene import scene_from_dict
    from glsim.scene.load import from_resolved as _from_resolved
    return scene_from_dict(*_from_resolved(json.loads(scene_json)))


def renderer_for(scene, backend: str | None = None) -> Renderer:
    """This thread's renderer for ``scene``: the current one if it shares mesh, reference
    and backend (its scene swapped), else a new one on this thread's GL context."""
    from glsim.workflows.library.keys import reference_key

    backend = backend or scene.render.backend
    r = thread_renderer(reference_key(scene, backend),
                        lambda: Renderer(scene, backend, ctx=thread_context() if backend == "gl" else None,
                                         truth_assembler=CompactAssembler()))
    r.scene = scene                # same mesh, reference, textures and programs; new options
    return r


def thread_renderer(key: str, make) -> Renderer:
    """This thread's renderer if it was made for ``key``; else the old one is closed (its
    textures, programs, targets — not the context) and ``make()`` gives the new one."""
    r = getattr(_LOCAL, "renderer", None)
    if r is not None and _LOCAL.key == key:
        return r
    if r is not None:
        r.close()
        _LOCAL.renderer = None
    _LOCAL.renderer, _LOCAL.key = make(), key
    return _LOCAL.renderer


def thread_context():
    """This thread's GL context (made on first use, on this pool worker's GPU if any): a GL
    context is current on one thread, so each worker thread has its own."""
    ctx = getattr(_LOCAL, "ctx", None)
    if ctx is None:
        from glsim.backends.gl.context import create_context
        ctx = _LOCAL.ctx = create_context(_DEVICE)
    return ctx


def release() -> None:
    """Close this thread's renderer, context and writer (tests and the in-process runner call it)."""
    r = getattr(_LOCAL, "renderer", None)
    if r is not None:
        r.close()
    ctx = getattr(_LOCAL, "ctx", None)
    if ctx is not None:
        ctx.release()
    w = getattr(_LOCAL, "writer", None)
    if w is not None:
        w.close()
    _LOCAL.renderer = _LOCAL.ctx = _LOCAL.key = _LOCAL.writer = None
    _LOCAL.masks = {}


# ---- handing images to the writer ------------------------------------------------------------------

MASKS = 16    # coverage masks kept per thread


def thread_writer():
    """This thread's writer (:func:`.writer.make_writer`: a writer process; made on first use,
    again if it has died)."""
    from glsim.workflows.library.writer import make_writer

    w = getattr(_LOCAL, "writer", None)
    if w is None or not w.alive():
        if w is not None:
            w.close()
        w = _LOCAL.writer = make_writer()
    return w


def _coverage(res) -> np.ndarray:
    """``res.coverage`` (the specimen's pixels), kept for the next variants this thread's
    renderer draws: it depends on the mesh, the camera and the step only, not on noise,
    lighting, optics or the speckle."""
    masks = _LOCAL.__dict__.setdefault("masks", {})
    key = (_LOCAL.key, repr(res.camera), res.step)
    if key not in masks:
        keep(masks, key, res.coverage, MASKS)
    return masks[key]


def render_task(task: dict) -> list[dict]:
    """Render the images of ``task`` (see :func:`make_task`) and hand them to this thread's
    writer; returns one manifest record per image once all are written. Raises
    :class:`WriteError` when a file cannot be written."""
    out = Path(task["out"])
    writer = thread_writer()               # first: a new writer process starts while the GL setup runs
    scene = _scene(task["scene"])
    r = renderer_for(scene, task.get("backend"))
    try:
        try:
            jobs = task["jobs"]   # pipelined, each image quantised as the camera writes it (on the GPU)
            with contextlib.closing(r.render_many({"camera": j["camera"], "step": j["step"], "truth": j["render_truth"],
                                                   "quantize": True} for j in jobs)) as results:
                for job, res in zip(jobs, results):
                    header, t = None, res.truth
                    if t is not None:
                        geometry = truthio.relpath(out / task["geometry"], (out / job["truth"]).parent)
                        header = truthcodec.image_header(res.camera, scene.cameras[0], r.reference.camera,
                                                         res.options.mode, job["step"], geometry,
                                                         task["geometry_sha256"],
                                                         motion.rolling_truth(scene, r.mesh, job["step"]))
                    writer.put(str(out), {**job, "bit_depth": res.camera.bit_depth}, res.image, _coverage(res),
                               None if t is None else (t.element, t.xi, t.eta), header, task["truth_dtype"],
                               res.seconds)
        except BaseException:
            try:
                writer.drain()
            except BaseException:
                pass
            raise
        return writer.drain()
    except OSError as exc:
        raise WriteError(f"{_final_name(exc) or out}: cannot be written ({exc.strerror or exc})"
                         + (" — the disk is full: free space, then run the same command again to resume"
                            if getattr(exc, "errno", None) == 28 else
                            " — check that the directory is writable, then run the same command again "
                            "to resume")) from None


def _final_name(exc: OSError) -> str | None:
    """The library file an OSError is about: a rename's target, or the file a temporary
    (``.NAME.XXXXXXXX.part…``, :func:`glsim.io.atomic.atomic_paths`) stands for."""
    import re

    name = exc.filename2 or exc.filename
    if name is None:
        return None
    m = re.fullmatch(r"\.(.+)\.[^.]+\.part[^/]*", Path(name).name)
    return str(Path(name).with_name(m.group(1))) if m else str(name)


class WriteError(GlsimError):
    """A library file could not be written (disk full, permissions); resuming fixes it."""


def make_task(variant, jobs, out: Path, geometry: str, geometry_sha256: str, truth_dtype: str,
              owners=frozenset()) -> dict:
    """The plain-data task of ``jobs`` (all of ``variant``); the jobs in ``owners`` render and
    write their truth file, the others only their image (their truth file is another job's)."""
    scene = variant.scene
    return {"variant": variant.id, "scene": scene.to_json(), "out": str(out), "backend": scene.render.backend,
            "geometry": geometry, "geometry_sha256": geometry_sha256, "truth_dtype": truth_dtype,
            "jobs": [{"variant": j.variant, "camera": j.camera, "step": j.step, "image": j.image, "truth": j.truth,
                      "render_truth": j in owners, "format": scene.output.format} for j in jobs]}


# ---- process pools ---------------------------------------------------------------------------------

_DEVICE: int | None = None   # this pool worker's EGL device (pool_init), None: glcontext's choice


def pool_init(devices=(), parent: int | None = None) -> None:
    """Local pool workers leave Ctrl-C to the parent (which stops them) and end when the
    ``parent`` process dies, however it dies (:mod:`.lifeline`); on a multi-GPU machine the
    k-th worker process the parent started renders on ``devices[k % len(devices)]`` (EGL
    device indices, :func:`glsim.backends.gl.context.gpu_devices`). k is the number the parent
    gave the process when it made it: no lock a killed worker could leave held."""
    import multiprocessing as mp
    import signal

    from glsim.workflows.library.lifeline import die_with_parent
    global _DEVICE
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if parent is not None:
        die_with_parent(parent)
    if devices:
        k = (getattr(mp.current_process(), "_identity", ()) or (os.getpid(),))[0] - 1
        _DEVICE = devices[k % len(devices)]


def gpus() -> list[int]:
    """EGL indices of the GPUs (not Mesa's software device); empty when none or unknown."""
    from glsim.backends.gl.context import egl_devices, gpu_devices
    return gpu_devices(egl_devices())
