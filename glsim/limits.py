"""Limits on what an input may ask glsim to build, checked before anything large is allocated.

A hostile or mistaken input — a header declaring 30000 × 30000 px, ``steps = "0-1000000000"``,
a camera of 100000² px, a library of 10¹⁰ variants — is refused by key with the limit and the fix
(:class:`~glsim.errors.SceneError`) instead of ending in a MemoryError or a GL error. Counts are
computed arithmetically, never by building the list first. The limits, documented here once:
"""
from __future__ import annotations

import os
import stat
from pathlib import Path

from glsim.errors import SceneError

MAX_IMAGE_SIDE = 16384        # px per side of a camera, a GL render target (W·√spp) and a reference image:
#                               the GL_MAX_TEXTURE_SIZE every GL 4.x driver offers (a GL render also checks
#                               its own context's); files' headers are read before they are decoded
MAX_IMAGE_PIXELS = 1 << 28    # px of a reference image (16384²)
MAX_SAMPLES_PER_PIXEL = 256   # render.samples_per_pixel: 16 × 16 sub-samples
MAX_PIECES = 16               # render.pieces: 256 linear pieces per quadratic element
MAX_STEPS = 10_000            # load steps asked for (--steps, a library's steps) or built (specimen.bulge.steps)
MAX_ELEMENTS = 4_000_000      # elements of a built-in specimen (plate nx·ny, bulge n_core and n_ring)
MAX_VALUES = 1_000_000        # values of one library [vary] key (range, linspace, draw n), and variants
MAX_IMAGES = 4_000_000        # images of one library (variants × cameras × steps)
MIN_DOTS_ACROSS = 2           # speckle dots across the reference image's shorter side: fewer is warned of
MAX_NESTING = 64              # nested tables and lists in a scene or spec file
MAX_NAME_BYTES = 255          # a file name's bytes (NAME_MAX): output.pattern's format widths, checked first
MAX_COORDINATE_MM = 1e9       # |x|, |y|, |z| of a node, a displacement, a pose's t, a camera centre (1000 km):
#                               far inside float64's range, so no product of lengths overflows in either backend
MAX_FOCAL_PX = 1e7            # fx, fy of a scene camera (a 10 m lens on 1 µm pixels), and |cx|, |cy|, |skew|
MAX_DISTORTION = 1e6          # |k1 … s4| of a scene camera (calibrations give |k| below 100)
BYTES_PER_SAMPLE = 64         # memory estimate of a render: per sub-sample (GL targets, image, raster) …
TRUTH_BYTES_PER_PIXEL = 128   # … and per pixel of truth maps; refused above the machine's memory
MAX_INDEX_BYTES = MAX_IMAGES * 512   # a library's or training set's library.json / training.json / manifest.csv:
#                               a row (an image, a variant, a shard) takes well under 512 bytes, so one glsim
#                               wrote is smaller; a larger one is refused before it is read (2 GiB)


def keep(cache: dict, key, value, most: int):
    """``cache[key] = value``, first dropping the oldest entries (insertion order) so that the
    cache holds at most ``most``: the bound on every cache kept per view, step or job. Returns
    ``value``."""
    if key not in cache:
        while len(cache) >= most:
            cache.pop(next(iter(cache)))
    cache[key] = value
    return value


def refuse_count(key: str, count: int, limit: int, what: str, fix: str) -> None:
    """SceneError if ``count`` of ``what`` exceeds ``limit``."""
    if count > limit:
        raise SceneError(key, f"gives {count:,} {what}, more than glsim's limit of {limit:,}", fix)


def check_image_size(key: str, width: int, height: int, what: str, fix: str,
                     max_side: int = MAX_IMAGE_SIDE) -> None:
    """SceneError if an image of ``width`` × ``height`` px exceeds ``max_side`` or MAX_IMAGE_PIXELS."""
    if max(width, height) > max_side or width * height > MAX_IMAGE_PIXELS:
        raise SceneError(key, f"{what} is {width} × {height} px; the limit is {max_side} px a side and "
                         f"{MAX_IMAGE_PIXELS:,} px in all", fix)


def memory_budget() -> int:
    """Bytes a process may use: the machine's memory, or less under an address-space limit."""
    import resource
    budget = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    soft = resource.getrlimit(resource.RLIMIT_AS)[0]
    return budget if soft == resource.RLIM_INFINITY else min(budget, soft)


def check_gl_target(key: str, size, spp: int, max_side: int = MAX_IMAGE_SIDE) -> None:
    """SceneError if a GL render of an image of ``size`` (W, H) at ``spp`` samples per pixel needs a
    target (W·√spp × H·√spp) over ``max_side`` px a side."""
    W, H = size
    s = round(spp ** 0.5)
    if max(W, H) * s > max_side:
        raise SceneError(key, f"a {W} × {H} px image at {spp} samples per pixel needs a {W * s} × {H * s} px GL "
                         f"render target, more than the limit of {max_side} px a side",
                         f"use at most {(max_side // max(W, H)) ** 2} samples per pixel, or backend = 'cpu'")


def check_memory(key: str, size, spp: int, truth: bool) -> None:
    """SceneError if rendering an image of ``size`` (W, H) at ``spp`` samples per pixel (and its truth)
    needs more memory than :func:`memory_budget` (estimate: BYTES_PER_SAMPLE, TRUTH_BYTES_PER_PIXEL)."""
    W, H = size
    need = W * H * (spp * BYTES_PER_SAMPLE + truth * TRUTH_BYTES_PER_PIXEL)
    budget = memory_budget()
    if need > budget:
        raise SceneError(key, f"a {W} × {H} px image at {spp} samples per pixel{' with truth' * truth} needs about "
                         f"{need / 2**30:.3g} GiB, more than the {budget / 2**30:.3g} GiB this process may use",
                         "use a smaller camera size or fewer samples per pixel" + (", or no truth" if truth else ""))


def _step_range(part: str, text: str, key: str) -> tuple[int, int]:
    """'3' → (3, 3), '0-3' → (0, 3); SceneError(key) for anything else ('0-' named as open)."""
    a, dash, b = part.partition("-")
    if dash and a.strip() and not b.strip():
        raise SceneError(key, f"the range {part.strip()!r} in {text!r} has no last step",
                         "give its last step too, e.g. 0-3")
    try:
        return int(a), int(b) if dash else int(a)
    except ValueError:
        raise SceneError(key, f"cannot read {text!r}", "write e.g. 0,2,5 or 0-3 (closed ranges, first-last)") from None


def parse_steps(text: str, key: str) -> list[int]:
    """'0,2,5' or '0-3' → load steps, counted before the list is made (at most MAX_STEPS). A range
    must be closed and ascending ('3-1' and '0-' are refused) and no step may be asked for twice."""
    parts = [_step_range(part, text, key) for part in text.split(",")]
    for a, b in parts:
        if b < a:
            raise SceneError(key, f"the range {a}-{b} in {text!r} runs backwards", f"write it first-last: {b}-{a}")
    refuse_count(key, sum(b - a + 1 for a, b in parts), MAX_STEPS, "load steps",
                 "select the load steps to render, e.g. 0-3 or 0,10,20")
    steps, seen = [], set()
    for a, b in parts:
        for s in range(a, b + 1):
            if s in seen:
                raise SceneError(key, f"{text!r} asks for step {s} twice", "name each load step once, e.g. 0-2,5")
            seen.add(s)
            steps.append(s)
    return steps


_DEEP = (f"nests tables or lists more than {MAX_NESTING} deep", "flatten the file")


def parse_nested(loads, text: str, key: str):
    """``loads(text)`` (json.loads, tomllib.loads), refusing (SceneError) tables or lists nested deeper
    than MAX_NESTING, where the parsers' own recursion would end in RecursionError."""
    try:
        data = loads(text)
    except RecursionError:
        raise SceneError(key, *_DEEP) from None
    check_nesting(data, key)
    return data


def check_nesting(data, key: str) -> None:
    """SceneError(key) if tables and lists in ``data`` nest deeper than MAX_NESTING (checked without recursion)."""
    todo = [(data, 0)]
    while todo:
        value, depth = todo.pop()
        if depth > MAX_NESTING:
            raise SceneError(key, *_DEEP)
        if isinstance(value, dict):
            todo += [(v, depth + 1) for v in value.values()]
        elif isinstance(value, (list, tuple)):
            todo += [(v, depth + 1) for v in value]


def not_a_file(path) -> str:
    """Why ``path`` cannot be read as an input file ("" for a regular file): missing, a directory,
    a FIFO, a device (/dev/zero never ends), …"""
    try:
        mode = os.stat(path).st_mode
    except OSError as exc:
        return "not found" if isinstance(exc, FileNotFoundError) else f"cannot be read ({exc.strerror or exc})"
    if stat.S_ISREG(mode):
        return ""
    kinds = ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISSOCK, "a socket"),
             (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"))
    return f"is {next((k for test, k in kinds if test(mode)), 'not a regular file')}, not a file"


def require_file(path, key: str, fix: str) -> Path:
    """``path`` as a Path if it is a regular file; else SceneError(key) saying what it is."""
    why = not_a_file(path)
    if why:
        named = f"file {path}" if why == "not found" else str(path)
        raise SceneError(key, f"{named} {why}" if key != str(path) else f"{'file ' * (why == 'not found')}{why}", fix)
    return Path(path)


# ---- files read from disk: what their headers declare, bounded before anything is read ----------

REFERENCE_BYTES_PER_PIXEL = 32   # memory estimate of reading a reference image: per pixel, besides its
#                                  decoded bytes (the float64 temporary of the scaling, the float32 image
#                                  kept and its copies in the render: a 4096² 16-bit one peaks at 26 B/px);
#                                  refused above the machine's memory
REFERENCE_DTYPES = ("uint8", "uint16", "float16", "float32", "float64")   # pixel types a reference may hold
MESH_BYTES_PER_NODE = 1024       # memory estimate of a mesh file, from the counts it declares: per node …
MESH_BYTES_PER_ELEMENT = 3072    # … and per element (reading, surface, the render's per-element work: a
#                                  250,000-quad .vtu renders in 0.79 GB, 2.7 KB a quad with its node, so a
#                                  10⁶-element mesh is estimated at 4 GB); refused above the machine's memory
MESH_BYTES_PER_TEXT_BYTE = 64    # … of a text mesh file that declares no counts (Abaqus), per byte of text
MAX_INCLUDE_DEPTH = 16           # Abaqus *INCLUDE files nested in each other


def check_need(key: str, need: int, what: str, fix: str) -> None:
    """SceneError(key) "``what`` need(s) about … GiB" if ``need`` bytes exceed :func:`memory_budget`."""
    budget = memory_budget()
    if need > budget:
        raise SceneError(key, f"{what} about {need / 2**30:.3g} GiB, more than the {budget / 2**30:.3g} GiB this "
                         "process may use", fix)


MESH_FIX = "give a coarser mesh (or only the visible surface), or run on a machine with more memory"


def check_mesh_memory(key: str, nodes: int, elements: int, extra_bytes: int = 0, what: str = "") -> None:
    """SceneError(key) if a mesh of ``nodes`` and ``elements`` (as a file declares them; negative
    counts refused), plus ``extra_bytes`` of its other data, needs more memory than
    :func:`memory_budget` (estimate: MESH_BYTES_PER_NODE, MESH_BYTES_PER_ELEMENT)."""
    if nodes < 0 or elements < 0:
        raise SceneError(key, f"declares {nodes:,} nodes and {elements:,} elements{what}",
                         "write or export the mesh file again")
    check_need(key, nodes * MESH_BYTES_PER_NODE + elements * MESH_BYTES_PER_ELEMENT + extra_bytes,
               f"declares {nodes:,} nodes and {elements:,} elements{what}, which need", MESH_FIX)


def read_bounded(path, limit: int = MAX_INDEX_BYTES) -> bytes:
    """The bytes of ``path``, refused (OSError EFBIG) past ``limit`` before any is read: its size from
    the open file's own status, and the read stops one byte past ``limit`` (a file that grows, or is
    no regular file, is caught too)."""
    import errno
    with open(path, "rb") as f:
        size = os.fstat(f.fileno()).st_size
        if size > limit:
            raise OSError(errno.EFBIG, f"{size} bytes, more than the {limit} a file of this kind holds", str(path))
        data = f.read(limit + 1)
    if len(data) > limit:
        raise OSError(errno.EFBIG, f"more than the {limit} bytes a file of this kind holds", str(path))
    return data
