"""Sensor noise (glsim/effects/noise.py, shaders/noise.glsl, shaders/noise.frag): the counter-based
generator, the three noise models on flat fields, variance-file validation, and the GL pass
against numpy."""
from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from glsim.effects import noise
from glsim.check import closed_forms
from glsim.errors import SceneError
from glsim.effects.noise import NoiseParams

N = 1000  # flat fields and generator checks use N × N = 1e6 samples
SEED = 20240611
IDX = np.arange(N * N, dtype=np.uint32)


def pcg_reference(x: int) -> int:
    """The PCG hash on Python ints, masked to 32 bits (independent of numpy's wrap-around)."""
    m = 0xFFFFFFFF
    state = (x * 747796405 + 2891336453) & m
    word = (((state >> ((state >> 28) + 4)) ^ state) * 277803737) & m
    return ((word >> 22) ^ word) & m


def write(tmp_path, name: str, text: str):
    path = tmp_path / name
    path.write_text(text)
    return path


def flat(level: float) -> np.ndarray:
    return np.full((N, N), level, np.float32)


def check_moments(sample: np.ndarray, mean: float, var: float, what: str) -> None:
    """Sample mean and variance within 5 standard errors of a normal sample of that size."""
    n = sample.size
    m, v = sample.mean(), sample.var(ddof=1)
    assert abs(m - mean) <= 5 * np.sqrt(var / n) + 1e-12, f"{what}: mean {m} vs {mean}"
    assert abs(v - var) <= 5 * var * np.sqrt(2 / (n - 1)), f"{what}: variance {v} vs {var}"


# ---- the generator -------------------------------------------------------------------------------
def test_pcg_hash_matches_python_integers():
    xs = [0, 1, 2, 12345, 0x7FFFFFFF, 0x80000000, 0xFFFFFFFE, 0xFFFFFFFF]
    xs += list(np.random.default_rng(0).integers(0, 2**32, 1000))
    got = noise.pcg_hash(np.array(xs, dtype=np.uint32))
    assert got.dtype == np.uint32
    assert [int(g) for g in got] == [pcg_reference(int(x)) for x in xs]
    # Python ints and int64 arrays wrap to uint32 as GLSL uint(int) does
    assert int(noise.pcg_hash(-1)) == pcg_reference(0xFFFFFFFF)


def test_uniform_mapping_never_zero_and_normal_always_finite():
    assert noise.unit_from_hash(np.uint32(0)) == 2.0 ** -24
    assert noise.unit_from_hash(np.uint32(0xFFFFFFFF)) == 1.0
    u = noise.uniform01(IDX, SEED, 0)
    assert u.min() > 0 and u.max() <= 1
    z = noise.standard_normal(IDX, SEED)
    assert np.isfinite(z).all()
    assert np.abs(z).max() <= np.sqrt(2 * 24 * np.log(2)) + 1e-12  # the 24-bit bound, 5.77


def test_uniform01_moments_and_independent_streams():
    u1 = noise.uniform01(IDX, SEED, 0)
    u2 = noise.uniform01(IDX, SEED, 1)
    n = u1.size
    for u in (u1, u2):
        assert abs(u.mean() - 0.5) <= 5 * np.sqrt(1 / 12 / n)
        # sd of the sample variance of a uniform: sqrt((1/80 − 1/144)/n)
        assert abs(u.var() - 1 / 12) <= 5 * np.sqrt((1 / 80 - 1 / 144) / n)
        counts = np.bincount((u * 64).astype(int).clip(0, 63), minlength=64)
        assert stats.chisquare(counts).pvalue > 0.01
    assert abs(np.corrcoef(u1, u2)[0, 1]) < 0.01
    # neighbouring pixels are not correlated either
    assert abs(np.corrcoef(u1[:-1], u1[1:])[0, 1]) < 0.01


def test_standard_normal_kolmogorov_smirnov():
    z = noise.standard_normal(IDX, SEED)
    assert np.isfinite(z).all()
    res = stats.kstest(z, "norm")
    assert res.pvalue > 0.01, res
    check_moments(z, 0.0, 1.0, "standard_normal")


def test_same_seed_same_image_bit_for_bit():
    img = np.random.default_rng(3).random((321, 457)).astype(np.float32)
    p = NoiseParams("gaussian", sigma=2.0)
    s = noise.stream_seed(7, 1, 3)
    a = noise.add_noise(img, p, 8, s)
    b = noise.add_noise(img.copy(), p, 8, s)
    assert a.dtype == np.float32 and a.shape == img.shape
    assert a.tobytes() == b.tobytes()
    assert noise.stream_seed(7, 1, 3) == s  # the seed itself is reproducible


def test_stream_seed_formula_and_independent_cameras_and_steps():
    with np.errstate(over="ignore"):
        expect = pcg_reference((pcg_reference((pcg_reference(42) + 1) & 0xFFFFFFFF) + 2) & 0xFFFFFFFF)
    assert noise.stream_seed(42, 1, 2) == expect
    seeds = {(c, t): noise.stream_seed(42, c, t) for c in range(3) for t in range(4)}
    seeds[("other scene", 0)] = noise.stream_seed(43, 0, 0)
    assert len(set(seeds.values())) == len(seeds)
    assert all(0 <= s < 2**32 for s in seeds.values())
    # 64-bit scene seeds are folded, not truncated
    assert noise.stream_seed(2**32 + 5, 0, 0) != noise.stream_seed(5, 0, 0)
    p = NoiseParams("gaussian", sigma=2.0)
    base = noise.add_noise(flat(0.5), p, 8, seeds[(0, 0)]).ravel() - 0.5
    for key in [(1, 0), (0, 1), (2, 3), ("other scene", 0)]:
        other = noise.add_noise(flat(0.5), p, 8, seeds[key]).ravel() - 0.5
        assert not np.array_equal(base, other)
        assert abs(np.corrcoef(base, other)[0, 1]) < 0.01, key


def test_bad_seeds_rejected():
    for bad in (-1, 1.5, "3"):
        with pytest.raises(SceneError, match="non-negative integer"):
            noise.stream_seed(bad, 0, 0)


# ---- the models on flat fields -------------------------------------------------------------------
@pytest.mark.parametrize("bits", [8, 12])
def test_gaussian_flat_fields(bits):
    """σ = 2 % of the dynamic range 2^bits: 5.12 DN at 8 bit, 81.92 DN at 12 bit, every level."""
    dn_max = 2**bits - 1
    p = NoiseParams("gaussian", sigma=2.0)
    sd_dn = 0.02 * 2**bits
    assert noise.noise_sigma(0.3, p, bits) * dn_max == pytest.approx(sd_dn, rel=1e-12)
    for k, level in enumerate((0.05, 0.5, 0.95)):
        out = noise.add_noise(flat(level), p, bits, noise.stream_seed(1, 0, k))
        dn = (out.astype(np.float64) - np.float32(level)) * dn_max
        check_moments(dn, 0.0, sd_dn**2, f"gaussian {bits} bit at {level}")


def test_heteroscedastic_table_is_honoured(tmp_path):
    path = write(tmp_path, "var.csv", "grey;variance\n200;64\n20;0.25\n")  # unsorted on purpose
    levels, var = noise.load_variance_table(path, 8)
    assert levels.tolist() == [20, 200] and var.tolist() == [0.25, 64]
    p = NoiseParams("heteroscedastic", variance_file=str(path))
    # DN: below the table (clamped), a row, half-way (interpolated), a row, above (clamped)
    for k, (dn, expect) in enumerate([(5, 0.25), (20, 0.25), (110, 32.125), (200, 64.0), (250, 64.0)]):
        level = dn / 255
        sigma = noise.noise_sigma(level, p, 8)
        assert (sigma * 255) ** 2 == pytest.approx(expect, rel=1e-6)
        out = noise.add_noise(flat(level), p, 8, noise.stream_seed(2, 0, k), table=(levels, var))
        d = (out.astype(np.float64) - np.float32(level)) * 255
        check_moments(d, 0.0, expect, f"heteroscedastic at DN {dn}")
    # the low and high levels really differ (16 ×in σ)
    lo = noise.add_noise(flat(20 / 255), p, 8, 11).std() * 255
    hi = noise.add_noise(flat(200 / 255), p, 8, 11).std() * 255
    assert hi / lo == pytest.approx(16, rel=0.01)


def test_heteroscedastic_12_bit_and_comma_without_header(tmp_path):
    path = write(tmp_path, "v12.csv", "# measured photon-transfer curve\n0, 4\n4095, 400\n\n")
    p = NoiseParams("heteroscedastic", variance_file=path)
    level = 1024 / 4095
    expect = 4 + 396 * 1024 / 4095
    out = noise.add_noise(flat(level), p, 12, 5)
    check_moments((out.astype(np.float64) - np.float32(level)) * 4095, 0.0, expect, "12-bit table")


@pytest.mark.parametrize("full_well,read", [(10000.0, 10.0), (2000.0, 3.0)])
def test_poisson_gaussian_flat_fields(full_well, read):
    """Variance in electrons² = signal electrons + read noise² (Gaussian approximation)."""
    p = NoiseParams("poisson_gaussian", full_well=full_well, read_noise=read)
    for k, level in enumerate((0.0, 0.05, 0.4, 0.9)):
        e = level * full_well
        out = noise.add_noise(flat(level), p, 12, noise.stream_seed(3, 0, k))
        d = (out.astype(np.float64) - np.float32(level)) * full_well
        check_moments(d, 0.0, np.float32(level) * full_well + read**2, f"poisson_gaussian at {e} e-")


def test_noise_is_not_clipped():
    out = noise.add_noise(flat(0.0), NoiseParams("gaussian", sigma=2.0), 8, 1)
    assert out.min() < 0  # clipping is quantisation's job


def test_variance_per_level_and_texture_layout(tmp_path):
    table = (np.array([0.0, 10.5, 255.0]), np.array([1.0, 2.0, 3.0]))
    per = noise.variance_per_level(table, 8)
    assert per.shape == (256,) and per[0] == 1 and per[255] == 3
    assert noise.variance_texture(table, 8).shape == (1, 256)
    assert noise.variance_texture(table, 12).shape == (1, 4096)
    tex16 = noise.variance_texture(table, 16)
    assert tex16.shape == (16, 4096) and tex16.dtype == np.float32   # 65536 > max texture width
    assert tex16.ravel()[65535] == pytest.approx(np.interp(65535, *table))


# ---- rejected input ------------------------------------------------------------------------------
@pytest.mark.parametrize("text,match", [
    ("grey;variance\n0;1\n128;abc\n", r"bad\.csv:3: expected two numbers"),
    ("0;1\n1;2;3\n", r"bad\.csv:2: expected two numbers"),
    ("0;1\n128;-2\n", r"bad\.csv:2: variance must be ≥ 0, got -2"),
    ("0;1\n300;2\n", r"bad\.csv:2: grey level 300 is outside 0…255 of a 8-bit camera — give grey"),
    ("-1;1\n100;2\n", r"bad\.csv:1: grey level -1 is outside"),
    ("0;1\n0.5;2\n1;3\n", r"bad\.csv: all grey levels are ≤ 1 .* normalized .* — give grey levels in camera DN"),
    ("0;1\nnan;2\n", r"bad\.csv:2: non-finite"),
    ("grey;variance\n128;4\n", r"bad\.csv: needs at least 2 rows"),
    ("", r"bad\.csv: needs at least 2 rows"),
    ("0;1\n10;2\n10;3\n", r"bad\.csv: grey level 10 is given twice"),
])
def test_bad_variance_files(tmp_path, text, match):
    path = write(tmp_path, "bad.csv", text)
    with pytest.raises(SceneError, match=match) as info:
        noise.load_variance_table(path, 8)
    assert " — " in str(info.value)  # every message says the fix


def test_missing_variance_file(tmp_path):
    with pytest.raises(SceneError, match=r"nope\.csv: noise variance file not found — give noise.variance_file"):
        noise.load_variance_table(tmp_path / "nope.csv", 8)
    p = NoiseParams("heteroscedastic", variance_file=tmp_path / "nope.csv")
    with pytest.raises(SceneError, match="not found"):
        noise.add_noise(flat(0.5)[:4, :4], p, 8, 1)
    with pytest.raises(SceneError, match="noise.variance_file: the heteroscedastic model needs"):
        noise.noise_sigma(0.5, NoiseParams("heteroscedastic"), 8)


@pytest.mark.parametrize("params,match", [
    (NoiseParams("salt_and_pepper"), "noise.model: unknown noise model 'salt_and_pepper' — use one of"),
    (NoiseParams("gaussian", sigma=-1), "noise.sigma: must be ≥ 0"),
    ({"model": "gaussian", "sigma": "2%"}, "noise.sigma: must be a number"),
    (NoiseParams("poisson_gaussian", full_well=0), "noise.full_well: must be > 0"),
    (NoiseParams("poisson_gaussian", read_noise=-3), "noise.read_noise: must be ≥ 0"),
])
def test_bad_parameters(params, match):
    with pytest.raises(SceneError, match=match):
        noise.noise_sigma(0.5, params, 8)


def test_plain_mapping_parameters():
    a = noise.add_noise(flat(0.5)[:8, :8], {"model": "gaussian", "sigma": 1.0}, 8, 9)
    b = noise.add_noise(flat(0.5)[:8, :8], NoiseParams("gaussian", sigma=1.0), 8, 9)
    assert a.tobytes() == b.tobytes()


# ---- GL against numpy (bounds from GLSL 4.50's precision rules: glsim.check.closed_forms) ---------

CHECK_COMP = """
#include "noise.glsl"
layout(local_size_x = 64) in;
layout(std430, binding = 0) writeonly buffer Hashes { uint hashes[]; };
layout(std430, binding = 1) writeonly buffer Uniforms { float uni[]; };
layout(std430, binding = 2) writeonly buffer Normals { float z[]; };
uniform uint u_seed;
uniform int u_count;
void main() {
    uint i = gl_GlobalInvocationID.x;
    if (int(i) >= u_count) return;
    hashes[i] = pcg_hash(i * 2654435761u);
    uni[2u * i] = uniform01(i, u_seed, 0u);
    uni[2u * i + 1u] = uniform01(i, u_seed, 1u);
    z[i] = standard_normal(i, u_seed);
}
"""


@pytest.mark.gl
def test_glsl_generator_matches_numpy(gl_ctx, tmp_path):
    """Hash and uniforms bit for bit; the normal within what GLSL's log, sqrt and cos allow
    (glsim.check.closed_forms.standard_normal, per sample)."""
    from glsim.backends.gl.programs import ProgramCache

    (tmp_path / "noise_check.comp").write_text(CHECK_COMP)
    cache = ProgramCache(gl_ctx, dirs=(tmp_path,))
    n = 1 << 18
    seed = noise.stream_seed(5, 1, 2)
    prog = cache.compute("noise_check.comp")
    prog["u_seed"].value = seed
    prog["u_count"].value = n
    bufs = [gl_ctx.buffer(reserve=n * 4), gl_ctx.buffer(reserve=n * 8), gl_ctx.buffer(reserve=n * 4)]
    for b, buf in enumerate(bufs):
        buf.bind_to_storage_buffer(b)
    prog.run(group_x=n // 64)
    hashes = np.frombuffer(bufs[0].read(), np.uint32)
    uni = np.frombuffer(bufs[1].read(), np.float32).reshape(n, 2)
    z = np.frombuffer(bufs[2].read(), np.float32)
    for buf in bufs:
        buf.release()
    cache.release()
    i = np.arange(n, dtype=np.uint32)
    with np.errstate(over="ignore"):
        assert np.array_equal(hashes, noise.pcg_hash(i * np.uint32(2654435761)))
    assert np.array_equal(uni[:, 0], noise.uniform01(i, seed, 0))
    assert np.array_equal(uni[:, 1], noise.uniform01(i, seed, 1))
    ref = noise.standard_normal(i, seed)
    bound = closed_forms.standard_normal(uni[:, 0], uni[:, 1])
    print(f"|z_GL − z| / bound: max {(np.abs(z - ref) / bound).max():.3g}")
    assert np.all(np.abs(z - ref) <= bound)


@pytest.mark.gl
@pytest.mark.parametrize("model", ["gaussian", "heteroscedastic", "poisson_gaussian"])
@pytest.mark.parametrize("bits", [8, 16])
def test_gl_noise_pass_matches_numpy(gl_ctx, tmp_path, model, bits):
    from glsim.backends.gl.backend import GLBackend

    top = 2**bits - 1
    path = write(tmp_path, "var.csv", f"grey;variance\n0;0.5\n{top // 3};3\n{top};{60 * (top / 255) ** 2}\n")
    p = {"gaussian": NoiseParams("gaussian", sigma=2.0),
         "heteroscedastic": NoiseParams("heteroscedastic", variance_file=path),
         "poisson_gaussian": NoiseParams("poisson_gaussian", full_well=10000.0, read_noise=5.0)}[model]
    # a non-square, odd-sized image with a gradient, out-of-range values and flat patches
    H, W = 301, 517
    img = np.random.default_rng(4).random((H, W)).astype(np.float32) * 1.1 - 0.05
    img[:50, :50] = 0.25
    seed = noise.stream_seed(99, 1, 2)
    table = noise.load_variance_table(path, bits) if model == "heteroscedastic" else None
    backend = GLBackend(np.zeros((4, 4), np.float32), ctx=gl_ctx)
    runs = [backend.noise_pass(img, p, bits, seed, table) for _ in range(2)]
    gl, again = (backend.read(t) for t in runs)
    for t in runs:
        t.release()
    backend.close()
    ref = noise.add_noise(img, p, bits, seed, table)
    assert gl.tobytes() == again.tobytes()  # reproducible on GL too
    diff = np.abs(gl.astype(np.float64) - ref)
    # per pixel within what float32 and GLSL's functions allow (glsim.check.closed_forms.noise)
    z, dz = closed_forms.normal_field(seed, (H, W))
    sigma = noise.noise_sigma(img, p, bits, table)
    bound = closed_forms.noise(img, z, dz, sigma, p, bits, table)
    print(f"{model} {bits} bit: max |GL − numpy| = {diff.max():.3g} of full scale, {(diff / bound).max():.3g} of its bound")
    assert np.all(diff <= bound)
    # the noise itself (not just the image) agrees: GL's σz against numpy's, relative to σ
    dz = np.abs((gl.astype(np.float64) - img) - (ref.astype(np.float64) - img)) / sigma
    assert np.median(dz) < 1e-3
