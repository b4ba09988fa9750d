"""Stage "noise": camera sensor noise (reference paper §2.2.3), numpy float64.

Mirrored name for name in ``shaders/noise.glsl`` (``pcg_hash``, ``uniform01``,
``standard_normal``, ``noise_sigma``); ``shaders/noise.frag`` is the full-screen pass that
does what :func:`add_noise` does.

Random numbers
    A counter-based generator, identical in numpy (uint32, wrap-around) and GLSL (``uint``):
    the PCG hash (Jarzynski & Olano 2020, "Hash functions for GPU rendering"). Nothing is
    stateful, so the same seed gives the same image bit for bit, on either backend, in any
    tile order. For pixel ``index = v·W + u`` (flat, row-major, v from the top) and uint32
    ``seed``::

        key(seed, stream) = pcg_hash(seed ^ pcg_hash(stream))
        h                 = pcg_hash(pcg_hash(index) ^ key(seed, stream))
        uniform01         = ((h >> 8) + 1) / 2^24                 ∈ (0, 1], never 0
        standard_normal   = sqrt(−2 ln u₁) · cos(2π u₂)           u₁ = stream 0, u₂ = stream 1

    The uniforms keep the top 24 bits of the hash so that float32 (GLSL) holds them exactly:
    GL and numpy draw the *same* uniforms, and only the float32 log/sqrt/cos differ. The
    normal is therefore bounded by sqrt(2·24·ln 2) = 5.77 (P(|z| > 5.77) = 8e-9 for a true
    normal, i.e. immaterial). Hashing the index first and then mixing in the key makes the
    fields of two seeds unrelated pseudo-random permutations (no XOR/shift structure between
    cameras). Independent fields per camera and load step come from
    :func:`stream_seed` (scene seed, camera index, step).

Noise models (σ in full-scale units, grey levels in [0, 1]; noise is added before
quantisation and is not clipped — :func:`glsim.io.images.quantize` clips)
    ``gaussian``          σ = sigma % of the dynamic range 2^bits grey levels, constant
                          (2 % of 8 bit = 5.12 DN → 5.12/255 of full scale).
    ``heteroscedastic``   variance per grey level from a CSV file ``grey;variance`` in DN and
                          DN² (the paper's input file), linearly interpolated, clamped at the
                          table's ends; σ = sqrt(var)/(2^bits − 1).
    ``poisson_gaussian``  e = max(I, 0)·full_well electrons; variance e + read_noise² (e⁻²);
                          σ = sqrt(e + read²)/full_well. The Poisson shot noise is drawn from
                          its Gaussian approximation: the variance is exact, the shape is
                          Gaussian (no skew, continuous) — fine above ~20 e⁻; at very low
                          signal the true distribution is skewed and discrete.
"""
from __future__ import annotations

import csv
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from glsim.errors import SceneError

MODELS = ("gaussian", "heteroscedastic", "poisson_gaussian")
UNIT_BITS = 24                      # bits of each hash kept for a uniform (exact in float32)
STREAM_U1, STREAM_U2 = 0, 1         # the Box–Muller streams
STREAM_PRNU, STREAM_DSNU = 2, 4     # the fixed-pattern maps' streams (each and the next)
TABLE_COLS_MAX = 4096               # the variance texture wraps into rows beyond this width



@dataclass(frozen=True)
class NoiseParams:
    """The noise settings (the scene's frozen dataclass may be used instead: same names)."""
    model: str = "gaussian"
    sigma: float = 0.0                     # gaussian: % of the dynamic range (2^bits levels)
    variance_file: str | Path | None = None  # heteroscedastic: CSV grey;variance (DN; DN²)
    full_well: float = 10000.0             # poisson_gaussian: electrons at full scale
    read_noise: float = 0.0                # poisson_gaussian: electrons rms


# ---- the generator ---------------------------------------------------------------------------
def pcg_hash(x) -> np.ndarray:
    """PCG hash of uint32 values (uint32 arithmetic with wrap-around, as GLSL ``uint``)."""
    x = _u32(x)
    with np.errstate(over="ignore"):
        state = x * np.uint32(747796405) + np.uint32(2891336453)
        word = ((state >> ((state >> np.uint32(28)) + np.uint32(4))) ^ state) * np.uint32(277803737)
        return (word >> np.uint32(22)) ^ word


def _u32(x) -> np.ndarray:
    """Integers → uint32 (modulo 2^32, as GLSL ``uint(int)``)."""
    x = np.asarray(x)
    if x.dtype == np.uint32:
        return x
    return (x.astype(np.int64) & 0xFFFFFFFF).astype(np.uint32)


def stream_key(seed, stream) -> np.ndarray:
    """The per-(seed, stream) key: pcg_hash(seed ^ pcg_hash(stream))."""
    return pcg_hash(_u32(seed) ^ pcg_hash(_u32(stream)))


def unit_from_hash(h) -> np.ndarray:
    """uint32 hash → float64 in (0, 1]: ((h >> 8) + 1) / 2^24 (exact in float32 too)."""
    h = _u32(h)
    return ((h >> np.uint32(32 - UNIT_BITS)).astype(np.float64) + 1.0) * 2.0 ** -UNIT_BITS


def uniform01(index, seed, stream) -> np.ndarray:
    """Uniform in (0, 1] for each flat pixel index of the given seed and stream."""
    h = pcg_hash(pcg_hash(_u32(index)) ^ stream_key(seed, stream))
    return unit_from_hash(h)


def standard_normal(index, seed, stream: int = STREAM_U1) -> np.ndarray:
    """Standard normal (Box–Muller, cosine branch) for each flat pixel index v·W + u, from the
    uniforms of streams ``stream`` and ``stream + 1`` (the temporal noise: 0 and 1)."""
    u1 = uniform01(index, seed, stream)
    u2 = uniform01(index, seed, stream + 1)
    return np.sqrt(-2.0 * np.log(u1)) * np.cos(2.0 * np.pi * u2)


def _seed_word(value, key: str) -> int:
    """A non-negative integer → one uint32 word (wider values are folded by hashing)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < 0:
        raise SceneError(key, f"must be a non-negative integer, got {value!r}", "give an integer ≥ 0")
    value = int(value)
    word = value & 0xFFFFFFFF
    value >>= 32
    while value:  # fold the higher words in, so 64-bit seeds stay distinct
        word = int(pcg_hash(np.uint32(word ^ int(pcg_hash(np.uint32(value & 0xFFFFFFFF))))))
        value >>= 32
    return word


def stream_seed(scene_seed: int, camera_index: int, step: int) -> int:
    """The uint32 seed of one image: hash(hash(hash(scene_seed) + camera) + step).

    Every (camera, step) gets its own, unrelated noise field; the same arguments give the
    same seed on every machine.
    """
    s = _seed_word(scene_seed, "seed")
    c = _seed_word(camera_index, "camera_index")
    t = _seed_word(step, "step")
    with np.errstate(over="ignore"):
        h = pcg_hash(np.uint32(s))
        h = pcg_hash(h + np.uint32(c))
        h = pcg_hash(h + np.uint32(t))
    return int(h)


def fixed_pattern_seed(scene_seed: int, camera_index: int) -> int:
    """The uint32 seed of a camera's fixed-pattern noise: hash(hash(scene_seed) + camera), the
    same at every load step (its maps draw on streams STREAM_PRNU and STREAM_DSNU, which the
    temporal noise never uses)."""
    s = _seed_word(scene_seed, "seed")
    c = _seed_word(camera_index, "camera_index")
    with np.errstate(over="ignore"):
        return int(pcg_hash(pcg_hash(np.uint32(s)) + np.uint32(c)))


def prnu_gain(shape: tuple[int, int], prnu: float, seed: int) -> np.ndarray:
    """The PRNU's gain per pixel, float64 (H, W): 1 + prnu/100 · z_p, z_p the standard normal map
    of ``seed`` (:func:`fixed_pattern_seed`) on stream STREAM_PRNU; ``prnu`` in % of the signal."""
    H, W = shape
    index = np.arange(H * W, dtype=np.uint32).reshape(H, W)
    return 1.0 + prnu / 100.0 * standard_normal(index, np.uint32(_seed_word(seed, "seed")), STREAM_PRNU)


def through_prnu(J, shape: tuple[int, int], prnu: float, seed: int):
    """The derivative of the fixed-pattern noise: an image Jacobian ``J`` (H·W × n, sparse) of
    the image of ``shape`` (H, W) before it → after the PRNU's gain (:func:`prnu_gain`); the DSNU
    adds an offset, with no derivative."""
    from scipy import sparse

    return sparse.diags(prnu_gain(shape, prnu, seed).ravel()) @ J


def fixed_pattern(image, prnu: float, dsnu: float, bit_depth: int, seed: int) -> np.ndarray:
    """EMVA 1288 fixed-pattern noise, float64 (H, W): image · :func:`prnu_gain` + dsnu/(2^bits − 1) · z_d,
    z_d the standard normal map of ``seed`` (:func:`fixed_pattern_seed`) on stream STREAM_DSNU;
    ``dsnu`` in DN."""
    I = np.asarray(image, np.float64)
    H, W = I.shape
    out = I * prnu_gain(I.shape, prnu, seed) if prnu else I
    if dsnu:
        index = np.arange(H * W, dtype=np.uint32).reshape(H, W)
        seed = np.uint32(_seed_word(seed, "seed"))
        out = out + dsnu / ((1 << _check_bits(bit_depth)) - 1) * standard_normal(index, seed, STREAM_DSNU)
    return out


# ---- parameters --------------------------------------------------------------------------------
def _get(params, name: str, default=None):
    if isinstance(params, Mapping):
        return params.get(name, default)
    return getattr(params, name, default)


def _number(params, name: str, *, positive: bool = False) -> float:
    value = _get(params, name)
    key = f"noise.{name}"
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise SceneError(key, f"must be a number, got {value!r}", _FIX[name])
    value = float(value)
    if not np.isfinite(value) or value < 0 or (positive and value == 0):
        raise SceneError(key, f"must be {'> 0' if positive else '≥ 0'}, got {value!r}", _FIX[name])
    return value


_FIX = {
    "sigma": "give the noise standard deviation in percent of the dynamic range (e.g. 2 for 2 %)",
    "full_well": "give the full-well capacity in electrons (e.g. 10000)",
    "read_noise": "give the read noise in electrons rms (e.g. 5)",
}


def _model(params) -> str:
    model = _get(params, "model")
    if model not in MODELS:
        raise SceneError("noise.model", f"unknown noise model {model!r}", f"use one of {', '.join(MODELS)}")
    return model


def _check_bits(bit_depth) -> int:
    if isinstance(bit_depth, bool) or not isinstance(bit_depth, (int, np.integer)) or not 1 <= bit_depth <= 16:
        raise SceneError("bit_depth", f"must be an integer 1…16, got {bit_depth!r}", "use 8, 10, 12 or 16")
    return int(bit_depth)


# ---- the variance table ------------------------------------------------------------------------
def load_variance_table(path, bit_depth: int) -> tuple[np.ndarray, np.ndarray]:
    """Read a heteroscedastic noise table: CSV rows ``grey;variance`` (``;`` or ``,``),
    grey levels in camera digital numbers DN (0 … 2^bits − 1), variance in DN².

    A first line that is not numeric is taken as a header; blank lines and lines starting
    with ``#`` are skipped. Returns (levels_dn, variance_dn2), float64, sorted by level.
    Raises SceneError naming the file (and line) and the fix.
    """
    bits = _check_bits(bit_depth)
    top = (1 << bits) - 1
    path = Path(path) if path is not None else None
    name = str(path)
    fmt = "write one 'grey;variance' row per line (grey in DN, variance in DN²)"
    if path is None or not path.is_file():
        raise SceneError(name, "noise variance file not found",
                         "give noise.variance_file as the path of a CSV file 'grey;variance'")
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise SceneError(name, f"cannot read the noise variance file ({exc})", fmt) from None
    rows: list[tuple[float, float]] = []
    first = True
    for lineno, line in enumerate(text.splitlines(), 1):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        delim = ";" if ";" in stripped else ","
        fields = [f.strip() for f in next(csv.reader([stripped], delimiter=delim))]
        while fields and fields[-1] == "":
            fields.pop()
        try:
            values = [float(f) for f in fields]
        except ValueError:
            values = None
        if values is None and first:  # a header line
            first = False
            continue
        first = False
        where = f"{name}:{lineno}"
        if values is None or len(values) != 2:
            raise SceneError(where, f"expected two numbers 'grey;variance', got {stripped!r}", fmt)
        level, var = values
        if not (np.isfinite(level) and np.isfinite(var)):
            raise SceneError(where, f"non-finite entry in {stripped!r}", fmt)
        if var < 0:
            raise SceneError(where, f"variance must be ≥ 0, got {var:g}",
                             "give the variance (DN², the square of the standard deviation)")
        if not 0 <= level <= top:
            raise SceneError(where, f"grey level {level:g} is outside 0…{top} of a {bits}-bit camera",
                             "give grey levels in the camera's digital numbers (DN), not normalized")
        rows.append((level, var))
    if len(rows) < 2:
        raise SceneError(name, f"needs at least 2 rows 'grey;variance', found {len(rows)}",
                         "give the variance at two or more grey levels")
    table = np.array(rows, dtype=np.float64)
    order = np.argsort(table[:, 0], kind="stable")
    levels, variance = table[order, 0], table[order, 1]
    if levels[-1] <= 1 and top > 1:
        raise SceneError(name, f"all grey levels are ≤ 1 (largest {levels[-1]:g}): they look "
                               f"normalized to full scale", f"give grey levels in camera DN 0…{top}")
    dup = np.flatnonzero(np.diff(levels) == 0)
    if len(dup):
        raise SceneError(name, f"grey level {levels[dup[0]]:g} is given twice",
                         "give each grey level once")
    return levels, variance


def variance_per_level(table, bit_depth: int) -> np.ndarray:
    """The table's variance (DN²) interpolated at every DN 0 … 2^bits − 1 (float64, 2^bits).

    This is the heteroscedastic model itself: between integer DN it is interpolated linearly
    (what :func:`noise_sigma` and the shader's ``u_variance`` texture do). For tables whose
    levels are integers it equals the linear interpolation of the table exactly.
    """
    bits = _check_bits(bit_depth)
    levels, variance = table
    return np.interp(np.arange(1 << bits, dtype=np.float64), levels, variance)


def variance_texture(table, bit_depth: int) -> np.ndarray:
    """The R32F texture data (rows, cols) float32 of :func:`variance_per_level`.

    One row of 2^bits texels up to 12 bits; 16-bit cameras wrap into rows of 4096 texels
    (texel n at (n % cols, n // cols)), since 65536 exceeds GL_MAX_TEXTURE_SIZE on many
    drivers (16384 on llvmpipe). The shader reads the width with textureSize.
    """
    per = variance_per_level(table, bit_depth).astype(np.float32)
    cols = min(per.size, TABLE_COLS_MAX)
    return np.ascontiguousarray(per.reshape(-1, cols))


def _table(params, bit_depth: int, table):
    if table is not None:
        return table
    path = _get(params, "variance_file")
    if path is None:
        raise SceneError("noise.variance_file", "the heteroscedastic model needs a variance file",
                         "give noise.variance_file: a CSV file 'grey;variance' (DN; DN²)")
    return load_variance_table(path, bit_depth)


# ---- the models --------------------------------------------------------------------------------
def noise_sigma(I, params, bit_depth: int, table=None) -> np.ndarray:
    """Noise standard deviation (full-scale units) at grey level(s) I (full scale), float64.

    ``table`` is (levels_dn, variance_dn2) from :func:`load_variance_table`; without it the
    heteroscedastic model reads ``params.variance_file``.
    """
    model = _model(params)
    bits = _check_bits(bit_depth)
    dn_max = float((1 << bits) - 1)
    I = np.asarray(I, dtype=np.float64)
    if model == "gaussian":
        sigma = _number(params, "sigma") / 100.0 * (1 << bits) / dn_max
        return np.full(I.shape, sigma)
    if model == "heteroscedastic":
        per = variance_per_level(_table(params, bits, table), bits)
        x = np.clip(I * dn_max, 0.0, dn_max)
        var = np.interp(x, np.arange(per.size, dtype=np.float64), per)
        return np.sqrt(np.maximum(var, 0.0)) / dn_max
    full_well = _number(params, "full_well", positive=True)
    read = _number(params, "read_noise")
    electrons = np.maximum(I, 0.0) * full_well
    return np.sqrt(electrons + read * read) / full_well


def add_noise(image, params, bit_depth: int, seed: int, table=None) -> np.ndarray:
    """image + σ(image)·z, z the standard normal field of ``seed`` (use :func:`stream_seed`).

    ``image`` (H, W) grey levels in full scale; returns float32 (H, W), not clipped.
    """
    img = np.asarray(image)
    if img.ndim != 2:
        raise ValueError(f"add_noise needs a (H, W) image, got shape {img.shape}")
    H, W = img.shape
    seed = _seed_word(seed, "seed")
    I = img.astype(np.float64)
    sigma = noise_sigma(I, params, bit_depth, table)
    index = np.arange(H * W, dtype=np.uint32).reshape(H, W)
    return (I + sigma * standard_normal(index, np.uint32(seed))).astype(np.float32)


# ---- what the GL pass needs ---------------------------------------------------------------------
def shader_defines(params) -> dict:
    """#defines of ``noise.frag`` for this model (NOISE_GAUSSIAN, …)."""
    return {f"NOISE_{_model(params).upper()}": None}


def shader_uniforms(params, bit_depth: int) -> dict:
    """Scalar uniforms of ``noise.frag`` for this model (u_noise_sigma in full scale, …).

    The heteroscedastic texture (``u_variance``) comes from :func:`variance_texture`.
    """
    model = _model(params)
    bits = _check_bits(bit_depth)
    if model == "gaussian":
        return {"u_noise_sigma": float(noise_sigma(0.0, params, bits))}
    if model == "heteroscedastic":
        return {"u_dn_max": float((1 << bits) - 1)}
    return {"u_full_well": _number(params, "full_well", positive=True),
            "u_read_noise": _number(params, "read_noise")}

