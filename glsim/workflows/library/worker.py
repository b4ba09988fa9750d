"""The worker side of a library: render a task (some images of one variant) and write its files.

A task is plain data (the variant's resolved scene as JSON, the images, the output directory)
so that it runs the same in this process, in a local process pool or on a Dask worker. Each
worker thread holds one GL context, made when its first task runs, and one
:class:`~glsim.render.Renderer`, reused for the next variant when that shares the mesh,
reference image and backend (only the scene's options change); otherwise the old renderer's
GL resources are released and a new one made on the same context. A GL context is current on
one thread, so the context and renderer are per thread (``threading.local``).

Encoding (quantising, TIFF/PNG, compact truth) and writing run on a writer thread while the
next image renders. Every image and its truth are written as one group under temporary names
and renamed truth first, image last (:func:`glsim.io.images.atomic_paths`): a task killed at
any moment leaves no truncated file under a final name, and a task run twice (a Dask worker
that died and its task rerun elsewhere) writes the same bytes again.
"""
from __future__ import annotations

import io as _io
import os
import queue
import threading
import time
from pathlib import Path

import numpy as np

from glsim.errors import GlsimError
from glsim.io import images as io
from glsim.io import truth as truthio
from glsim.render import Renderer

_LOCAL = threading.local()


class CompactRaster:
    """The truth a library stores (:func:`glsim.io.truth.compact`): ``element`` (H, W) int32,
    ``xi``/``eta`` (n,) float64 of the n covered pixels in raster order."""

    def __init__(self, element, xi, eta):
        self.element, self.xi, self.eta = element, xi, eta


class CompactRenderer(Renderer):
    """A Renderer whose truth is only the compact (element, ξ, η): no float64 map of the
    positions or reference coordinates is made (the truth file determines them), and the
    backend's full-size raster is dropped as soon as the covered pixels are gathered."""

    def _truth(self, size, deformed, raster, evaluate=None) -> CompactRaster:
        W, H = size
        return CompactRaster(*truthio.compact(raster["element"].reshape(H, W), raster["xi"], raster["eta"]))


def _scene(scene_json: str):
    import json

    from glsim.scene import scene_from_dict
    from glsim.scene.load import from_resolved as _from_resolved
    return scene_from_dict(*_from_resolved(json.loads(scene_json)))


def renderer_for(scene, backend: str | None = None) -> Renderer:
    """This thread's renderer for ``scene``: the current one if it shares mesh, reference
    and backend (its scene swapped), else a new one on this thread's GL context."""
    from glsim.workflows.library.spec import reference_key

    backend = backend or scene.render.backend
    r = thread_renderer(reference_key(scene, backend),
                        lambda: CompactRenderer(scene, backend, ctx=thread_context() if backend == "gl" else None))
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
    """Close this thread's renderer and context (tests and the in-process runner call it)."""
    r = getattr(_LOCAL, "renderer", None)
    if r is not None:
        r.close()
    ctx = getattr(_LOCAL, "ctx", None)
    if ctx is not None:
        ctx.release()
    _LOCAL.renderer = _LOCAL.ctx = _LOCAL.key = None


# ---- encoding and writing ------------------------------------------------------------------------

def image_bytes(image: np.ndarray, bit_depth: int, fmt: str) -> bytes:
    """The bytes :func:`glsim.io.images.write_image` would write."""
    data = io.quantize(image, bit_depth)
    buf = _io.BytesIO()
    if fmt == "tiff":
        import tifffile
        tifffile.imwrite(buf, data, photometric="minisblack")
        return buf.getvalue()
    import imageio.v3 as iio
    return iio.imwrite("<bytes>", data, extension=".png")


def write_group(files: list[tuple[Path, bytes]]) -> None:
    """Write (path, bytes) pairs as one group: temporaries first, renamed in the order given."""
    with io.atomic_paths([p for p, _ in files]) as tmps:
        for tmp, (_, data) in zip(tmps, files):
            with open(tmp, "wb") as f:
                f.write(data)


def _encode_and_write(out: Path, job: dict, res, header: dict | None, dtype: str) -> dict:
    t0 = time.perf_counter()
    cam = res.camera
    data = image_bytes(res.image, cam.bit_depth, job["format"])
    t1 = time.perf_counter()
    files = []
    rec = {"variant": job["variant"], "camera": job["camera"], "step": job["step"], "file": job["image"],
           "bytes": len(data), "sha256": truthio.sha256_bytes(data), "truth_file": job["truth"],
           "truth_bytes": 0, "truth_sha256": "", "render_s": res.seconds, "saturated": res.saturated,
           "covered": res.covered}
    if job["render_truth"]:
        t = res.truth
        tdata = truthio.encode_compact(t.element, t.xi, t.eta, header, dtype)
        rec["truth_bytes"], rec["truth_sha256"] = len(tdata), truthio.sha256_bytes(tdata)
        files.append((out / job["truth"], tdata))
    t2 = time.perf_counter()
    files.append((out / job["image"], data))
    write_group(files)
    t3 = time.perf_counter()
    rec.update(encode_s=t1 - t0, truth_s=(t2 - t1) if job["render_truth"] else 0.0, write_s=t3 - t2)
    return rec


class _Writer:
    """One background thread encoding and writing while the caller renders the next image."""

    def __init__(self, depth: int = 2):
        self.q: queue.Queue = queue.Queue(depth)
        self.records: list[dict] = []
        self.error: BaseException | None = None
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self):
        while True:
            item = self.q.get()
            if item is None:
                return
            if self.error is None:
                try:
                    self.records.append(_encode_and_write(*item))
                except BaseException as exc:  # reported by close()
                    self.error = exc

    def put(self, *item):
        if self.error is not None:
            raise self.error
        self.q.put(item)

    def close(self) -> list[dict]:
        self.q.put(None)
        self.thread.join()
        if self.error is not None:
            raise self.error
        return self.records


def render_task(task: dict) -> list[dict]:
    """Render and write the images of ``task`` (see :func:`make_task`); returns one manifest
    record per image. Raises :class:`WriteError` when a file cannot be written."""
    out = Path(task["out"])
    scene = _scene(task["scene"])
    r = renderer_for(scene, task.get("backend"))
    writer = _Writer()
    try:
        try:
            for job in task["jobs"]:
                res = r.render(job["camera"], job["step"], truth=job["render_truth"])
                header = None
                if job["render_truth"]:
                    header = truthio.image_header(res.camera, scene.cameras[0], r.reference.camera,
                                                  res.options.mode, job["step"],
                                                  truthio.relpath(out / task["geometry"], (out / job["truth"]).parent),
                                                  task["geometry_sha256"])
                writer.put(out, job, res, header, task["truth_dtype"])
        except BaseException:
            try:
                writer.close()
            except BaseException:
                pass
            raise
        return writer.close()
    except OSError as exc:
        raise WriteError(f"{exc.filename or out}: cannot be written ({exc.strerror or exc})"
                         + (" — the disk is full: free space, then run the same command again to resume"
                            if getattr(exc, "errno", None) == 28 else
                            " — check that the directory is writable, then run the same command again "
                            "to resume")) from None


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
