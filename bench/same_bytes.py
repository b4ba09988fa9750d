"""Same-bytes guard for refactors of the renderer: SHA-256 of the images and truth of a fixed set
of scenes on both backends.

    python bench/same_bytes.py record   # write tests/fixtures/same_bytes-*.json on this machine
    python bench/same_bytes.py check    # compare with it (tests/test_same_bytes.py runs this)

The hashes hold for one machine (llvmpipe's code generation follows the CPU, numpy's SIMD loops
too), so the fixture records the machine it was made on and the test compares only there.
A refactor that changes a hash must say why in its commit.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import platform
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
# one fixture per GL pixel stage (GLSIM_PIXEL_STAGE: llvmpipe's default is fragment)
STAGE = os.environ.get("GLSIM_PIXEL_STAGE") or "fragment"   # unset: the driver's, fragment on llvmpipe
FIXTURE = ROOT / "tests" / "fixtures" / f"same_bytes-{STAGE}.json"
SIZE = (64, 48)


def _digest(*arrays) -> str:
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(str((a.dtype.str, a.shape)).encode())
        h.update(a.tobytes())
    return h.hexdigest()


def _truth_arrays(t):
    return [t.mask, t.element, t.xi, t.eta, t.ref_uv]


def scenes():
    """(name, scene, render options) of every case."""
    from glsim.scene import bulge_scene, load_scene
    from glsim.scene.optional import Exposure, Psf, Sensor, Vignetting
    from glsim.scene.presets import demo_effects

    base = bulge_scene(size=SIZE, steps=2)
    out = []
    for mode in ("exact", "q4", "fast"):
        for spp in (1, 4):
            out.append((f"bulge-{mode}-{spp}spp", base, dict(mode=mode, samples_per_pixel=spp)))
    rep = dataclasses.replace
    effects = {
        "lit-defocus-noise": demo_effects(base),
        "psf-gauss": rep(base, psf=Psf(kind="gaussian", sigma=0.8)),
        "psf-airy": rep(base, psf=Psf(kind="airy", wavelength_nm=550.0, f_number=8.0, pixel_pitch=0.0044)),
        "vignetting": rep(base, vignetting=Vignetting(natural=True, radial=(-0.1,))),
        "sensor-fpn": rep(base, sensor=Sensor(fill_factor=0.6, prnu=1.0, dsnu=0.5)),
        "motion": rep(base, exposure=Exposure(time=0.01, samples=3, velocity=(0.5, 0.0, 0.0))),
        "rolling": rep(base, sensor=Sensor(line_time=1e-4),
                       exposure=Exposure(time=0.001, samples=1, velocity=(2.0, 0.0, 0.0))),
    }
    for name, sc in effects.items():
        out.append((f"effect-{name}", sc, dict(mode="exact", samples_per_pixel=1)))
    q8 = load_scene(ROOT / "examples" / "hole_c3d20r" / "scene.toml")
    q8 = rep(q8, cameras=tuple(rep(c, size=SIZE, fx=c.fx * SIZE[0] / c.size[0], fy=c.fy * SIZE[0] / c.size[0],
                                   cx=(SIZE[0] - 1) / 2, cy=(SIZE[1] - 1) / 2) for c in q8.cameras))
    out.append(("q8-patch-exact", q8, dict(mode="exact", samples_per_pixel=1)))
    return out


def record_hashes() -> dict:
    from glsim.render import Renderer

    result = {}
    for name, scene, opts in scenes():
        for backend in ("cpu", "gl"):
            with Renderer(scene, backend=backend) as r:
                step = 1
                res = r.render("cam1", step=step, truth=True, quantize=True, **opts)
                key = f"{name}/{backend}"
                result[key + "/image"] = _digest(res.image)
                result[key + "/truth"] = _digest(*_truth_arrays(res.truth))
                if name == "bulge-exact-1spp":
                    jr = r.render("cam1", step=step, jacobian=True, **opts)
                    J = jr.jacobian.tocsr()
                    result[key + "/jacobian"] = _digest(J.indptr, J.indices, J.data)
    result.update(library_hashes())
    return result


def library_hashes() -> dict:
    """A two-variant library (noise σ, both backends' worker path is GL) through the CLI: the
    worker's compact truth and images, file by file."""
    import subprocess
    import tempfile

    from glsim.io.truth import read as read_truth

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        text = (ROOT / "examples" / "bulge.toml").read_text().replace("size = [1624, 1234]", f"size = [{SIZE[0]}, {SIZE[1]}]")
        text = text.replace("6818.0", f"{6818.0 * SIZE[0] / 1624}").replace("cx = 811.5", f"cx = {(SIZE[0] - 1) / 2}")
        text = text.replace("cy = 616.5", f"cy = {(SIZE[1] - 1) / 2}")
        (tmp / "bulge.toml").write_text(text)
        (tmp / "lib.toml").write_text('scene = "bulge.toml"\nseed = 7\nmode = "grid"\nsteps = [0, 1]\n'
                                      'truth = true\n[vary]\nnoise.sigma = [0.5, 2.0]\n')
        subprocess.run([sys.executable, "-m", "glsim.cli", "library", str(tmp / "lib.toml"), "-o",
                        str(tmp / "lib"), "--workers", "1", "-q"], check=True)
        out, truths = {}, []
        for f in sorted((tmp / "lib").rglob("*")):
            name = "library/" + f.relative_to(tmp / "lib").as_posix()
            if f.is_file() and f.suffix in (".tif", ".tiff", ".png"):
                out[name] = hashlib.sha256(f.read_bytes()).hexdigest()
            elif f.is_file() and f.suffix == ".truth":   # the maps, not the container (its header varies)
                t = read_truth(f)
                truths.append(_digest(t.element, t.xi, t.eta, t.mask))
        out["library/truth"] = hashlib.sha256(" ".join(sorted(truths)).encode()).hexdigest()
        return out


def machine() -> dict:
    from glsim.backends.gl.context import create_context

    ctx = create_context()
    try:
        renderer = ctx.info["GL_RENDERER"] + " | " + ctx.info["GL_VERSION"]
    finally:
        ctx.release()
    info = Path("/proc/cpuinfo").read_text().splitlines() if Path("/proc/cpuinfo").exists() else []
    cpu = next((line.split(":", 1)[1].strip() for line in info if line.startswith("model name")), platform.processor())
    # the instruction sets decide llvmpipe's code and numpy's SIMD loops: one model name can hide several
    flags = next((line.split(":", 1)[1].split() for line in info if line.startswith("flags")), [])
    simd = sorted(f for f in flags if f.startswith(("avx", "sse", "fma")))
    return {"gl": renderer, "cpu": cpu, "simd": " ".join(simd), "numpy": np.__version__,
            "python": platform.python_version()}


def main(argv) -> int:
    what = argv[1] if len(argv) > 1 else "check"
    got = record_hashes()
    here = machine()
    if what == "record":
        FIXTURE.parent.mkdir(exist_ok=True)
        FIXTURE.write_text(json.dumps({"machine": here, "hashes": got}, indent=1, sort_keys=True) + "\n")
        print(f"recorded {len(got)} hashes on {here}")
        return 0
    want = json.loads(FIXTURE.read_text())
    if want["machine"] != here:
        print(f"fixture made on {want['machine']}, this is {here}: not comparable")
        return 3
    diff = sorted(k for k in want["hashes"] if want["hashes"][k] != got.get(k))
    for k in diff:
        print("changed:", k)
    print(f"{len(want['hashes']) - len(diff)} of {len(want['hashes'])} hashes equal")
    return 1 if diff else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
