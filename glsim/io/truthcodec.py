"""The compact truth file's coder: per pixel the element index and the local coordinates
(ξ, η), stored losslessly in a fraction of the space of the full float64 maps (read back by
:mod:`glsim.io.truth`).

File layout (version 2), little endian::

    b"GLTRUTH2"  SHA-256 (32 bytes)  uint64 header length  header (UTF-8 JSON)  blobs…

The SHA-256 is of everything after it (header length, header, blobs): the reader verifies it
before it believes a byte, so a flipped bit, a cut or an inserted byte is refused, never
decoded into other maps. Version 1 files (``b"GLTRUTH1"``, no checksum) are refused with the
fix (re-render them). The header names the image's camera (``camera``), camera 0 (``camera0``,
the frame of the positions), the reference camera, the render mode, the load step, the geometry
file (relative path and SHA-256) and the blobs (offset and length after the header). Blob
``element``: the (H, W) int32 element map (−1 = background), zstd. Blob ``local``: (ξ, η) of
the covered pixels in raster order. For
``dtype = "float64"`` (default, lossless) each value's IEEE bits, as int64, are predicted along
the row from the previous two pixels of the same element (second difference; first difference
or none at the start of a run), the residuals zigzag-coded, byte-shuffled and zstd-compressed:
decoding is exact integer arithmetic, so the values come back bit for bit. ``dtype =
"float32"`` stores the values rounded to float32 (|Δξ| ≤ 3e-8), byte-shuffled and zstd'd.
ξ and η are element-local coordinates: finite and within ±LOCAL_BOUND, checked when written and
when read.
"""
from __future__ import annotations

import hashlib
import json
import struct

import numpy as np

from glsim.errors import GlsimError
from glsim.io.cameras import camera_to_dict
from glsim.scene.camera import Camera

MAGIC = b"GLTRUTH2"
OLD_MAGIC = b"GLTRUTH1"       # version 1: no checksum, refused
FORMAT = "glsim-compact-truth"
VERSION = 2
DIGEST = 32                   # bytes of the SHA-256 after the magic
PREFIX = len(MAGIC) + DIGEST + 8   # magic, digest, header length
MAX_HEADER = 1 << 20          # bytes of JSON header at most (three cameras and a motion: a few kB)
DTYPES = ("float64", "float32")
ZSTD_LEVEL = 3
LOCAL_BOUND = 2.0             # |ξ|, |η| at most: the element's domain [−1, 1] widened by 1, far beyond what
#                               the renderer gives (float64 Newton: within 1e-6 of the domain; the fast mode
#                               with one linear piece per curved side of a quadratic element: 2 % outside)


class TruthFileError(GlsimError):
    """A truth or geometry file that cannot be read (the message names the file and why)."""


# ---- the lossless float64 coder ------------------------------------------------------------------

def _runs(element: np.ndarray):
    """Covered pixels in raster order and where each continues its left neighbour's element
    run (``same1``) and that run for two pixels (``same2``)."""
    H, W = element.shape
    flat = element.ravel()
    idx = np.flatnonzero(flat >= 0)
    e = flat[idx]
    same1 = np.zeros(len(idx), bool)
    same1[1:] = (idx[1:] == idx[:-1] + 1) & (e[1:] == e[:-1]) & (idx[1:] % W != 0)
    same2 = np.zeros(len(idx), bool)
    same2[2:] = same1[2:] & same1[1:-1]
    return idx, same1, same2


def _shuffle(a: np.ndarray) -> np.ndarray:
    """Byte planes: all first bytes, then all second bytes, … (compresses small integers well);
    a contiguous uint8 array (zstd reads it in place)."""
    return np.ascontiguousarray(np.ascontiguousarray(a).view(np.uint8).reshape(-1, a.itemsize).T)


def _unshuffle(data: bytes, dtype, n: int) -> np.ndarray:
    size = np.dtype(dtype).itemsize
    planes = np.frombuffer(data, np.uint8)
    if planes.size != n * size:
        raise ValueError(f"{planes.size} bytes where {n} values of {size} bytes were expected")
    return np.ascontiguousarray(planes.reshape(size, n).T).view(dtype).ravel()


def _seg_cumsum(v: np.ndarray, start: np.ndarray) -> np.ndarray:
    """Cumulative sums of int64 ``v`` restarting wherever ``start`` (start[0] is True);
    wraps modulo 2⁶⁴ like the encoder's differences, so the round trip is exact."""
    cs = np.cumsum(v, dtype=np.int64)
    before = np.concatenate((np.zeros(1, np.int64), cs[:-1]))
    first = np.maximum.accumulate(np.where(start, np.arange(len(v)), 0))
    return cs - before[first]


def encode_local(values: np.ndarray, same1: np.ndarray, same2: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """float64 values (n,) → zigzag residual codes (n,) uint64 (see the module text), into
    ``out`` (n,) uint64 if given. Integer arithmetic wraps modulo 2⁶⁴ (as the decoder's)."""
    iv = np.ascontiguousarray(values, np.float64).view(np.int64)
    r = np.empty(len(iv), np.int64) if out is None else out.view(np.int64)
    r[:] = iv
    d1 = iv[1:] - iv[:-1]
    np.copyto(r[1:], d1, where=same1[1:])
    np.copyto(r[2:], d1[1:] - d1[:-1], where=same2[2:])
    sign = (r >> np.int64(63)).view(np.uint64)
    u = r.view(np.uint64)
    np.left_shift(u, np.uint64(1), out=u)
    np.bitwise_xor(u, sign, out=u)
    return u


def decode_local(codes: np.ndarray, same1: np.ndarray, same2: np.ndarray) -> np.ndarray:
    """The inverse of :func:`encode_local`: exact, bit for bit."""
    if not len(codes):
        return np.zeros(0)
    r = (codes >> np.uint64(1)).view(np.int64) ^ -(codes & np.uint64(1)).view(np.int64)
    with np.errstate(over="ignore"):
        d = _seg_cumsum(np.where(same1, r, 0), ~same2)          # first differences inside runs
        iv = _seg_cumsum(np.where(same1, d, r), ~same1)
    return iv.view(np.float64)


def _zstd():
    import zstandard
    return zstandard


# ---- cameras in the header ------------------------------------------------------------------------

camera_dict = camera_to_dict   # (glsim.io.cameras: the one camera codec)


# ---- writing ----------------------------------------------------------------------------------------

def compact(element: np.ndarray, xi: np.ndarray, eta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What a truth file stores of the maps ``element`` (H, W) int (−1 background) and
    ``xi``/``eta`` (H, W) float64: the int32 element map and (ξ, η) of its n covered pixels in
    raster order, (n,) float64 each — gathered from the maps, no full-size copy of them made."""
    el = np.ascontiguousarray(element, np.int32)
    idx = np.flatnonzero(el.ravel() >= 0)
    return el, np.asarray(xi, np.float64).ravel()[idx], np.asarray(eta, np.float64).ravel()[idx]


def encode(element: np.ndarray, xi: np.ndarray, eta: np.ndarray, header: dict,
           dtype: str = "float64") -> bytes:
    """A truth file's bytes. ``element`` (H, W) int (−1 background), ``xi``/``eta`` (H, W)
    float64 (values outside the covered pixels are ignored); ``header``: the metadata
    (cameras, mode, step, geometry, …; see :func:`image_header`)."""
    return encode_compact(*compact(element, xi, eta), header, dtype)


def encode_compact(el: np.ndarray, xs: np.ndarray, es: np.ndarray, header: dict, dtype: str = "float64") -> bytes:
    """:func:`encode` from :func:`compact`'s arrays: ``el`` (H, W) int32, ``xs``/``es`` (n,)
    float64 of the n covered pixels."""
    if dtype not in DTYPES:
        raise GlsimError(f"truth dtype {dtype!r} is not one of {DTYPES}; use float64 (lossless) or float32")
    H, W = el.shape
    idx, same1, same2 = _runs(el)
    n = len(idx)
    if len(xs) != n or len(es) != n:
        raise ValueError(f"{len(xs)} ξ and {len(es)} η values for {n} covered pixels")
    for name, v in (("ξ", xs), ("η", es)):
        k = local_problem(v)
        if k >= 0:    # (a file the reader would refuse is never written)
            raise TruthFileError(f"the truth's {name} at pixel ({idx[k] % W}, {idx[k] // W}) of element {el.flat[idx[k]]} "
                                 f"is {float(v[k])!r}, outside the element's local coordinates [−1, 1] widened to "
                                 f"±{LOCAL_BOUND:g} — the element is degenerate or folded: check the mesh there")
    cz = _zstd().ZstdCompressor(level=ZSTD_LEVEL)
    if dtype == "float64":
        local = np.empty(2 * n, np.uint64)
        encode_local(xs, same1, same2, out=local[:n])
        encode_local(es, same1, same2, out=local[n:])
        codec = "int64-row-delta2-zigzag+shuffle+zstd"
    else:
        local = np.empty(2 * n, np.float32)
        local[:n], local[n:] = xs, es
        codec = "float32+shuffle+zstd"
    blobs = {"element": cz.compress(np.ascontiguousarray(el, np.int32)), "local": cz.compress(_shuffle(local))}
    head = {"format": FORMAT, "version": VERSION, "size": [W, H], "covered": int(n), "dtype": dtype,
            "codec": {"element": "int32+zstd", "local": codec}, **header}
    return assemble(head, blobs)


def assemble(header: dict, blobs: dict[str, bytes]) -> bytes:
    """A truth file's bytes from its header (``blobs`` offsets added) and its blobs, in order."""
    offsets, pos = {}, 0
    for name, b in blobs.items():
        offsets[name] = [pos, len(b)]
        pos += len(b)
    text = json.dumps({**header, "blobs": offsets}, sort_keys=True).encode()
    return container(text, b"".join(blobs.values()))


def container(text: bytes, payload: bytes) -> bytes:
    """MAGIC, the SHA-256 of what follows it, the header length, ``text`` (the header) and ``payload``."""
    length = struct.pack("<Q", len(text))
    digest = hashlib.sha256(length)
    digest.update(text)
    digest.update(payload)
    return b"".join([MAGIC, digest.digest(), length, text, payload])


def zstd_bound(n: int) -> int:
    """The most bytes zstd compresses ``n`` bytes into (ZSTD_COMPRESSBOUND): a blob longer than
    this for the size its header gives is refused before it is read."""
    return n + (n >> 8) + (((128 << 10) - n) >> 11 if n < 128 << 10 else 0)


def local_problem(values: np.ndarray) -> int:
    """The index of the first of ``values`` (n,) that is not finite or exceeds ±LOCAL_BOUND; −1 if none."""
    bad = ~(np.abs(values) <= LOCAL_BOUND)          # NaN compares False: bad
    return int(np.argmax(bad)) if bad.any() else -1


def image_header(camera: Camera, camera0: Camera, reference_camera: Camera, mode: str, step: int,
                 geometry: str, geometry_sha256: str, rolling: dict | None = None) -> dict:
    """The metadata of one image's truth. ``geometry``: the geometry file's path relative to
    the truth file's directory; ``rolling``: a rolling shutter's rigid motion (line_time,
    velocity, angular_velocity, centre: :func:`glsim.effects.motion.rolling_truth`), from which
    each row's deformed positions are made."""
    return {"camera": camera_dict(camera), "camera0": camera_dict(camera0),
            "reference_camera": camera_dict(reference_camera), "mode": mode, "step": int(step),
            "geometry": geometry, "geometry_sha256": geometry_sha256, **({"rolling": rolling} if rolling else {})}
