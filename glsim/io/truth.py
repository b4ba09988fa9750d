"""Compact ground truth: per pixel the element index and the local coordinates (ξ, η) — which,
with the mesh and its displacements, determine every other truth map — stored losslessly in a
fraction of the space of the full float64 maps, and read back as full maps on demand.

A library writes per image one ``{stem}.truth`` file and per distinct specimen one geometry
file (``geometry/{hash}.npz``: placed undeformed nodes, quads, element labels, the
displacements of the rendered load steps). ``load(path)`` reads either truth file glsim writes:
a library's ``.truth`` (:class:`CompactTruth`) or ``glsim render --truth``'s ``*_truth.npz``
(:class:`MapTruth`, the full float64 maps), with the same ``maps()`` and ``at(points)``;
:meth:`CompactTruth.maps` returns the same maps as ``Renderer.render(..., truth=True).truth``
(bit for bit for ``element``, ``xi``, ``eta``, ``X_undeformed``, ``X_deformed``), and
:meth:`CompactTruth.at` gives the 3-D reference and deformed positions and the displacement at
any camera-0 pixel coordinates in the reference state (what a DIC result is compared with).

The file format and its coder: :mod:`glsim.io.truthcodec`; geometry files:
:mod:`glsim.io.geometryfile`. Only numpy, zstandard and glsim's scene layer are used (and, for
``MapTruth.at``, the mesh loader of :mod:`glsim.imaging.reference`): no GL, no renderer.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import struct
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path, PurePosixPath
from typing import Callable

import numpy as np

from glsim.errors import SceneError
from glsim.io.images import EXTENSIONS
from glsim.limits import check_image_size, not_a_file, parse_nested
from glsim.scene import quadratic as qd
from glsim.io.cameras import camera_from_dict
from glsim.scene.camera import Camera, project_camera_frame, to_camera
from glsim.scene.optional import motion_centre, rigid_state, row_offsets
from glsim.io.truthcodec import (DIGEST, DTYPES, FORMAT, LOCAL_BOUND, MAGIC, MAX_HEADER, OLD_MAGIC, PREFIX,
                                 VERSION, TruthFileError, _runs, _unshuffle, _zstd, decode_local, local_problem,
                                 zstd_bound)
from glsim.io.geometryfile import Geometry, read_geometry
from glsim.scene.locate import PointTruth, element_evaluator, points_truth, rows_at
from glsim.io.npzfile import NpzError, read_npz


# ---- the truth maps (what Renderer.render(..., truth=True) returns, and maps() decodes) ------------

@dataclass(frozen=True, eq=False)
class Truth:
    """Per-pixel ground truth at pixel centres. Float maps are NaN where ``mask`` is False.

    ``element``: element index (−1 = background); ``xi``, ``eta``: local coordinates in
    [−1, 1] (FE corner order); ``ref_uv``: reference-image coordinates (px) the pixel was
    given; ``X_undeformed``/``X_deformed``: the material point in camera 0's frame (mm),
    evaluated in float64 from (element, ξ, η) on first access (``positions`` makes both), so
    that who needs only (element, ξ, η), as a library's compact truth, does not pay for them.
    With motion over the exposure (:mod:`glsim.effects.motion`) the maps are of the mid-exposure
    state, and ``uv_start``/``uv_end`` (H, W, 2) where the pixel's material point is in the
    image (px) at the exposure's start and end; None otherwise.
    """
    mask: np.ndarray
    element: np.ndarray
    xi: np.ndarray
    eta: np.ndarray
    ref_uv: np.ndarray
    positions: Callable[[], tuple[np.ndarray, np.ndarray]] = dataclasses.field(repr=False)
    uv_start: np.ndarray | None = None
    uv_end: np.ndarray | None = None

    FIELDS = ("mask", "element", "xi", "eta", "ref_uv", "X_undeformed", "X_deformed")
    MOTION = ("uv_start", "uv_end")   # written when present

    @cached_property
    def _X(self) -> tuple[np.ndarray, np.ndarray]:
        return self.positions()

    @property
    def X_undeformed(self) -> np.ndarray:
        return self._X[0]

    @property
    def X_deformed(self) -> np.ndarray:
        return self._X[1]

    def as_dict(self) -> dict[str, np.ndarray]:
        return {name: getattr(self, name) for name in self.FIELDS + self.MOTION if getattr(self, name) is not None}


def pixel_positions(mask: np.ndarray, points) -> Callable[[], tuple[np.ndarray, np.ndarray]]:
    """``Truth.positions`` for the covered pixels of ``mask`` (H, W): ``points()`` gives their
    undeformed and deformed points (n, 3), camera 0's frame, mm; NaN elsewhere."""
    def make():
        H, W = mask.shape
        Xu, Xd = np.full((H, W, 3), np.nan), np.full((H, W, 3), np.nan)
        Xu[mask], Xd[mask] = points()
        return Xu, Xd
    return make


# ---- reading ----------------------------------------------------------------------------------------

class CompactTruth:
    """One image's truth as read from a ``.truth`` file: ``element``, ``xi``, ``eta``,
    ``mask`` decoded on access; :meth:`maps` and :meth:`at` need the geometry file."""

    def __init__(self, path: Path, header: dict, blobs: bytes, geometry: Geometry | None = None):
        self.path = path
        self.header = header
        self._blobs = blobs
        self._geometry = geometry

    # -- metadata
    @property
    def size(self) -> tuple[int, int]:
        return tuple(self.header["size"])

    @property
    def step(self) -> int:
        return int(self.header["step"])

    @property
    def mode(self) -> str:
        return self.header["mode"]

    def _camera(self, name: str) -> Camera:
        try:
            return camera_from_dict(self.header[name])
        except (KeyError, TypeError, ValueError) as exc:   # SceneError is a ValueError
            raise TruthFileError(f"{self.path}: its header's {name} is damaged ({exc}){DAMAGED}") from None

    @cached_property
    def camera(self) -> Camera:
        return self._camera("camera")

    @cached_property
    def camera0(self) -> Camera:
        """Camera 0, the frame of the positions."""
        return self._camera("camera0")

    @cached_property
    def reference_camera(self) -> Camera:
        return self._camera("reference_camera")

    # -- the stored maps
    def _blob(self, name: str, size: int) -> bytes:
        """Blob ``name`` decompressed, refused unless it is exactly ``size`` bytes (never more is made)."""
        off, n = self.header["blobs"][name]
        zstd = _zstd()
        data = self._blobs[off:off + n]
        try:
            declared = zstd.frame_content_size(data)
            if declared in (-1, size):
                data = zstd.ZstdDecompressor().decompress(data, max_output_size=size)
        except zstd.ZstdError as exc:
            raise TruthFileError(f"{self.path}: blob {name!r} does not decompress ({exc}){DAMAGED}") from None
        if declared not in (-1, size) or len(data) != size:
            raise TruthFileError(f"{self.path}: blob {name!r} holds {declared if declared != -1 else len(data)} bytes "
                                 f"where the header's size gives {size}{DAMAGED}")
        return data

    @cached_property
    def element(self) -> np.ndarray:
        """(H, W) int64 element index (0-based, the mesh's quads order; −1 = background)."""
        W, H = self.size
        el = np.frombuffer(self._blob("element", 4 * W * H), np.int32).reshape(H, W).astype(np.int64)
        covered = int(np.count_nonzero(el >= 0))
        if el.min(initial=-1) < -1 or covered != self.header["covered"]:
            raise TruthFileError(f"{self.path}: its element map holds {covered} covered pixels (header: "
                                 f"{self.header['covered']}) or indices below −1{DAMAGED}")
        return el

    @property
    def mask(self) -> np.ndarray:
        return self.element >= 0

    @cached_property
    def _local(self) -> tuple[np.ndarray, np.ndarray]:
        W, H = self.size
        idx, same1, same2 = _runs(self.element)
        n = len(idx)
        raw = self._blob("local", 2 * n * np.dtype(self.header["dtype"]).itemsize)
        if self.header["dtype"] == "float64":
            codes = _unshuffle(raw, np.uint64, 2 * n)
            vals = [decode_local(codes[:n], same1, same2), decode_local(codes[n:], same1, same2)]
        else:
            v = _unshuffle(raw, np.float32, 2 * n).astype(np.float64)
            vals = [v[:n], v[n:]]
        out = []
        for name, v in zip(("ξ", "η"), vals):
            k = local_problem(v)
            if k >= 0:
                raise TruthFileError(f"{self.path}: its {name} at pixel ({idx[k] % W}, {idx[k] // W}) is {float(v[k])!r}, "
                                     f"outside the element's local coordinates [−1, 1] widened to ±{LOCAL_BOUND:g}"
                                     f"{DAMAGED}")
            a = np.full(H * W, np.nan)
            a[idx] = v
            out.append(a.reshape(H, W))
        return out[0], out[1]

    @property
    def xi(self) -> np.ndarray:
        return self._local[0]

    @property
    def eta(self) -> np.ndarray:
        return self._local[1]

    # -- geometry
    @property
    def geometry(self) -> Geometry:
        """The geometry file the header names, confined to the library (:func:`geometry_path`) and
        verified against the header's SHA-256 before it is parsed."""
        if self._geometry is None:
            path = geometry_path(self.path, self.header["geometry"])
            if not_a_file(path):
                raise TruthFileError(f"{self.path}: its geometry file {path} is missing; keep the library's "
                                     "geometry/ folder beside the variant folders, or re-run the library "
                                     "command on the directory to write it")
            self._geometry = read_geometry(path, self.header["geometry_sha256"])
        return self._geometry

    def maps(self) -> Truth:
        """The full maps, as the renderer's ``Truth`` (X in camera 0's frame, mm)."""
        g, mask = self.geometry, self.mask
        W, H = self.size
        e = self.element[mask]
        if e.size and e.max() >= len(g.quads):
            raise TruthFileError(f"{self.path}: element {e.max()} is not in its geometry file ({len(g.quads)} "
                                 f"elements){DAMAGED}")
        xi, eta = self.xi[mask], self.eta[mask]
        shape, points = element_evaluator(g, e)     # (the renderer's own evaluation, bit for bit)
        cam0, step = self.camera0, self.step
        deformed = (lambda: shape(points(g.deformed(step)), xi, eta)) if "rolling" not in self.header else \
            (lambda: self._rows_deformed(g, e, xi, eta))
        positions = pixel_positions(mask, lambda: (to_camera(shape(points(g.nodes), xi, eta), cam0),
                                                   to_camera(deformed(), cam0)))
        ref = np.full((H, W, 2), np.nan)
        rc = self.reference_camera
        Xr = points(to_camera(g.nodes, rc))
        if self.mode == "q4":      # the paper's mapping: the nodes' reference points, by the shape functions
            ref[mask] = shape(project_camera_frame(Xr, rc)[0], xi, eta)
        else:                      # the reference camera's projection of the material point
            ref[mask] = project_camera_frame(shape(Xr, xi, eta), rc)[0]
        return Truth(mask=mask, element=self.element, xi=self.xi, eta=self.eta, ref_uv=ref, positions=positions)

    def _rolling(self):
        """The header's rolling shutter: (velocity, angular velocity or None, centre, each row's
        time (H,) s from the step's)."""
        try:
            m = self.header["rolling"]
            v, c = (np.asarray(m[k], np.float64).reshape(3) for k in ("velocity", "centre"))
            w = None if m["angular_velocity"] is None else np.asarray(m["angular_velocity"], np.float64).reshape(3)
            return v, w, c, row_offsets(self.size[1], float(m["line_time"]))
        except (KeyError, TypeError, ValueError) as exc:
            raise TruthFileError(f"{self.path}: its header's rolling shutter is damaged ({exc}){DAMAGED}") from None

    def _rows_deformed(self, g: Geometry, e: np.ndarray, xi: np.ndarray, eta: np.ndarray) -> np.ndarray:
        """A rolling shutter's deformed points (n, 3) world mm: each row's in its own state, the
        header's rigid motion ``rolling`` of the step's nodes at that row's time (as the
        renderer's rows, bit for bit)."""
        v, w, c, taus = self._rolling()
        shape, nodes = element_evaluator(g, e)[0], g.deformed(self.step)
        rows = np.nonzero(self.mask)[0]
        out = np.empty((len(e), 3))
        for r in np.unique(rows):
            sel = rows == r
            out[sel] = shape(qd.element_points(g.quads, g.patches, e[sel], rigid_state(nodes, taus[r], v, w, c)),
                             xi[sel], eta[sel])
        return out


    def at(self, points, step: int | None = None) -> PointTruth:
        """Ground truth at ``points`` (N, 2) — pixel coordinates (u, v) of camera 0 in the
        reference (undeformed) state, as a DIC reports its subset centres: the material point
        there (camera 0's ray intersected exactly with the undeformed mesh, the nearest hit),
        its position undeformed and at ``step`` (default: this image's step; with a rolling
        shutter, in the state of the row of this image where the point is seen), camera 0's
        frame, mm. Points whose ray misses the specimen are ``valid`` False and NaN."""
        pt = points_truth(self.geometry, self.camera0, points, self.step if step is None else step)
        if step is not None or "rolling" not in self.header:
            return pt
        return rows_at(pt, self.geometry, self.camera, self.camera0, *self._rolling())


class MapTruth:
    """One image's truth as ``glsim render --truth`` writes it: the full float64 maps of a
    ``*_truth.npz``. :meth:`at` takes the mesh, camera 0 and the image's load step from the
    render's ``scene.json`` (the first one in the file's folder or above it)."""

    def __init__(self, path: Path, arrays: dict[str, np.ndarray]):
        self.path = path
        self._arrays = arrays

    @property
    def size(self) -> tuple[int, int]:
        H, W = self.mask.shape
        return W, H

    @property
    def mask(self) -> np.ndarray:
        return self._arrays["mask"]

    @property
    def element(self) -> np.ndarray:
        return self._arrays["element"]

    @property
    def xi(self) -> np.ndarray:
        return self._arrays["xi"]

    @property
    def eta(self) -> np.ndarray:
        return self._arrays["eta"]

    def maps(self) -> Truth:
        """The maps as written (the renderer's ``Truth``)."""
        a = self._arrays
        return Truth(mask=a["mask"], element=a["element"], xi=a["xi"], eta=a["eta"], ref_uv=a["ref_uv"],
                     positions=lambda: (a["X_undeformed"], a["X_deformed"]), uv_start=a.get("uv_start"),
                     uv_end=a.get("uv_end"))

    @cached_property
    def _render(self) -> tuple[Geometry, Camera, int, Camera, tuple | None]:
        """The render's geometry, camera 0, this image's load step and camera, and its rolling
        shutter's rigid motion (velocity, angular velocity or None, centre, the rows' times) or
        None, from its scene.json."""
        from glsim.scene import load_scene
        from glsim.io.fe import specimen_mesh

        folder = next((d for d in self.path.parents if (d / "scene.json").is_file()), None)
        if folder is None:
            raise TruthFileError(f"{self.path}: no scene.json in its folder or above; at() needs the render's "
                                 "scene.json — keep the truth file inside the directory glsim render wrote")
        scene = load_scene(folder / "scene.json")
        mesh = specimen_mesh(scene)
        image = (self.path.parent / self.path.name[:-len("_truth.npz")]).relative_to(folder).as_posix()
        ext = EXTENSIONS[scene.output.format]
        step, cam = next(((s, c) for s in range(mesh.n_steps) for c in scene.cameras if str(PurePosixPath(
            scene.output.pattern.format(camera=c.name, step=s, ext=ext)).with_suffix("")) == image), (None, None))
        if step is None:
            raise TruthFileError(f"{self.path}: {folder / 'scene.json'} names no image {image}.{ext}; keep the truth "
                                 "file where glsim render wrote it, under its own name")
        ex, line = scene.exposure, scene.sensor.line_time if scene.sensor is not None else 0.0
        rolling = None
        if line > 0 and ex is not None and ex.rigid:
            rolling = (np.asarray(ex.velocity or (0.0, 0.0, 0.0), np.float64),
                       None if ex.angular_velocity is None else np.asarray(ex.angular_velocity, np.float64),
                       motion_centre(ex, mesh, step), row_offsets(cam.height, line))
        return mesh_geometry(mesh), scene.cameras[0], step, cam, rolling

    @property
    def step(self) -> int:
        """The image's load step (from the render's scene.json)."""
        return self._render[2]

    def at(self, points, step: int | None = None) -> PointTruth:
        """As :meth:`CompactTruth.at` (a rolling shutter's rigid motion from the scene; one whose
        states interpolate between load steps: the step's state)."""
        g, cam0, own, cam, rolling = self._render
        pt = points_truth(g, cam0, points, own if step is None else step)
        return pt if step is not None or rolling is None else rows_at(pt, g, cam, cam0, *rolling)


def mesh_geometry(mesh) -> Geometry:
    """A :class:`~glsim.scene.mesh.Mesh` with all its load steps as the :class:`Geometry` that
    :func:`points_truth` reads (its patches too, for a quadratic mesh)."""
    return Geometry(mesh.nodes, mesh.quads, tuple(range(mesh.n_steps)), np.stack(mesh.displacements),
                    mesh.element_labels, mesh.patches)


def geometry_path(truth_path: Path, rel) -> Path:
    """The geometry file ``rel`` (a truth header's ``geometry``) of the truth file at
    ``truth_path``, refused (TruthFileError) unless it stays in the library: a relative path,
    either in the truth file's folder or ``../geometry/NAME`` (the library's geometry folder beside
    its truth folder: what the library writes), no other ``..``, and inside that folder's library
    once symbolic links are followed."""
    parts = PurePosixPath(rel).parts if isinstance(rel, str) and rel and "\\" not in rel else ()
    up = parts[:2] == ("..", "geometry")
    inner = parts[2:] if up else parts
    root = truth_path.parent.parent if up else truth_path.parent
    where = truth_path.parent.joinpath(*parts) if parts else truth_path.parent
    if (not inner or PurePosixPath(rel).is_absolute() or any(p in ("..", ".") for p in inner)
            or not Path(os.path.realpath(where)).is_relative_to(os.path.realpath(root))):
        raise TruthFileError(f"{truth_path}: its header names the geometry file {rel!r}, outside the library "
                             f"(not followed){DAMAGED}")
    return where


def read(path: str | Path, geometry: Geometry | None = None) -> CompactTruth:
    """Read a ``.truth`` file (the maps are decoded when first used). Its header is checked first:
    the sizes it declares against :mod:`glsim.limits` and the file's length, before anything
    more is read; then the whole file against its SHA-256, before anything is decompressed (with
    its output bounded to the declared size)."""
    path = Path(path)
    why = not_a_file(path)
    if why:
        raise TruthFileError(f"{path}: cannot be read ({why}); check the path")
    try:
        with open(path, "rb") as f:
            head = f.read(PREFIX)
            if head[:len(OLD_MAGIC)] == OLD_MAGIC:
                raise TruthFileError(f"{path}: a compact truth file of format version 1 (written by an older glsim, "
                                     "without a checksum), which this glsim does not read; re-render it: run the "
                                     "library command with --force (glsim library SPEC -o DIR --force)")
            if head[:len(MAGIC)] != MAGIC or len(head) < PREFIX:
                raise TruthFileError(f"{path}: not a glsim compact truth file (it does not start with {MAGIC!r}); "
                                     "give a library's .truth file, or a *_truth.npz of glsim render --truth")
            (n,) = struct.unpack("<Q", head[-8:])
            room = os.fstat(f.fileno()).st_size - PREFIX
            if n > min(room, MAX_HEADER):
                raise TruthFileError(f"{path}: {'truncated' if n > room else 'damaged'} (its header length {n:,} "
                                     f"exceeds the {min(room, MAX_HEADER):,} bytes it may have){DAMAGED}")
            text = f.read(n)
            header = _header(path, text)
            end = max(o + k for o, k in header["blobs"].values())
            if room - n != end:
                raise TruthFileError(f"{path}: {'truncated' if room - n < end else 'damaged'} ({room - n} data bytes "
                                     f"where its header gives {end}){DAMAGED}")
            blobs = f.read(end)
    except OSError as exc:
        raise TruthFileError(f"{path}: cannot be read ({exc.strerror or exc}); check the path") from None
    digest = hashlib.sha256(head[-8:])
    digest.update(text)
    digest.update(blobs)
    if digest.digest() != head[len(MAGIC):len(MAGIC) + DIGEST]:
        raise TruthFileError(f"{path}: fails its checksum (SHA-256){DAMAGED}")
    return CompactTruth(path, header, blobs, geometry)


DAMAGED = "; the file is damaged: run `glsim library DIR --verify`, then the library command again to re-render it"


def _header(path: Path, text: bytes) -> dict:
    """A truth file's header, its fields and sizes checked (TruthFileError naming the field)."""
    try:
        header = parse_nested(json.loads, text.decode("utf-8"), str(path))
    except (ValueError, SceneError) as exc:
        raise TruthFileError(f"{path}: its header is damaged ({exc}){DAMAGED}") from None
    if not isinstance(header, dict) or header.get("format") != FORMAT or header.get("version") != VERSION:
        got = (header.get("format"), header.get("version")) if isinstance(header, dict) else (None, None)
        raise TruthFileError(f"{path}: format {got[0]!r} version {got[1]!r} is not {FORMAT!r} version {VERSION}; "
                             "read it with the glsim that wrote it")
    count = lambda v: isinstance(v, int) and not isinstance(v, bool) and v >= 0  # noqa: E731
    blobs, size = header.get("blobs"), header.get("size")
    checks = {"size": isinstance(size, list) and len(size) == 2 and all(count(v) and v > 0 for v in size),
              "covered": count(header.get("covered")), "dtype": header.get("dtype") in DTYPES,
              "step": count(header.get("step")), "mode": isinstance(header.get("mode"), str),
              "geometry": isinstance(header.get("geometry"), str),
              "geometry_sha256": isinstance(header.get("geometry_sha256"), str),
              "blobs": isinstance(blobs, dict) and set(blobs) == {"element", "local"} and all(
                  isinstance(b, list) and len(b) == 2 and all(map(count, b)) for b in blobs.values())}
    bad = next((k for k, ok in checks.items() if not ok), None)
    if bad:
        raise TruthFileError(f"{path}: its header's {bad} is {header.get(bad)!r}{DAMAGED}")
    try:
        check_image_size(f"{path}: size", *size, "the image", "re-render it with the library command")
    except SceneError as exc:
        raise TruthFileError(str(exc)) from None
    if header["covered"] > size[0] * size[1]:
        raise TruthFileError(f"{path}: its header's covered {header['covered']} exceeds its {size[0]} × {size[1]} "
                             f"px{DAMAGED}")
    sizes = {"element": 4 * size[0] * size[1], "local": 2 * header["covered"] * np.dtype(header["dtype"]).itemsize}
    for name, (_, n) in blobs.items():
        if n > zstd_bound(sizes[name]):    # (bounded before it is read)
            raise TruthFileError(f"{path}: its header's blob {name!r} has {n:,} bytes, more than zstd makes of the "
                                 f"{sizes[name]:,} bytes its size gives{DAMAGED}")
    return header


def load(path: str | Path, geometry: Geometry | None = None) -> CompactTruth | MapTruth:
    """Any truth file glsim writes: a library's ``.truth`` (:func:`read`; ``geometry``: its
    geometry, if already read) or ``glsim render --truth``'s ``*_truth.npz``."""
    path = Path(path)
    if not path.name.endswith("_truth.npz"):
        return read(path, geometry)
    why = not_a_file(path)
    if why:
        raise TruthFileError(f"{path}: cannot be read ({why}); check the path")
    try:
        arrays = read_npz(path, Truth.FIELDS, Truth.MOTION, check=_maps_problem)
    except NpzError as exc:
        raise TruthFileError(f"{exc}; give a *_truth.npz that glsim render --truth wrote, or a library's .truth "
                             "file") from None
    return MapTruth(path, arrays)


def _maps_problem(members: dict) -> str:
    """What in a ``*_truth.npz``'s declared arrays (name → :class:`~glsim.io.npzfile.Member`)
    does not fit a truth of one image ("" if nothing): every map (H, W) or (H, W, k ≤ 3), one
    size for all, within the image limits."""
    H, W = members["mask"].shape[:2] if len(members["mask"].shape) == 2 else (0, 0)
    for m in members.values():
        if m.shape[:2] != (H, W) or len(m.shape) > 3 or (len(m.shape) == 3 and m.shape[2] > 3):
            return f"{m.name} is {m.shape}, not a map of the mask's {H} × {W} px"
    try:
        check_image_size("mask", W, H, "the image", "")
    except SceneError as exc:
        return str(exc)
    return ""


def relpath(target: str | Path, start: str | Path) -> str:
    """``target`` relative to directory ``start``, with forward slashes."""
    return Path(os.path.relpath(target, start)).as_posix()
