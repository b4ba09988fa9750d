"""The pass × define tables of docs/shaders.md, made from :func:`glsim.backends.gl.plan.plan`
over the kinds of render it distinguishes (tests/test_shaders_doc.py holds the page to them)."""
from __future__ import annotations

import dataclasses
import itertools

from glsim.backends.gl.plan import EffectsShape, plan
from glsim.backends.gl.programs import PROGRAMS
from glsim.scene import Render
from glsim.scene.camera import Camera, Distortion

# the steps whose programs take the plan's defines (the deformation passes)
DEFORM_STEPS = {"fast", "fast_ids", "fast_shade", "layer", "listed", "overflow", "newton"}
_PIN = Camera(name="pinhole", size=(64, 48), fx=800.0, fy=800.0, cx=31.5, cy=23.5)
_BARREL = dataclasses.replace(_PIN, name="barrel", distortion=Distortion(k1=-0.1))
_EFFECTS = (None, EffectsShape(lights=2, multiplicative=True),
            EffectsShape(blur=True, scheme="expansion", aperture=0.5, vignette=True, psf="separable",
                         fixed_pattern=True, noise=True),
            EffectsShape(blur=True, scheme="hybrid", psf="2d"), EffectsShape(blur=True, scheme="disk"),
            EffectsShape(blur=True, scheme="gather"), EffectsShape(blur=True, scheme="separable"))


def plans():
    """A plan of every kind of render: each mode, precision, supersampling (1, 4), sub-sample
    placement, curved pieces or none, pinhole or distorted cameras, a driver with and without
    float64, the effects' shapes, quantised or not, in both pixel stages."""
    for mode, precision, spp, newton, pieces, cams, fp64, fx, quantize, stage in itertools.product(
            ("fast", "q4", "exact"), ("fp64", "fp32"), (1, 4), (False, True), (None, 2),
            ((_PIN, _PIN), (_BARREL, _PIN), (_PIN, _BARREL)), (True, False), _EFFECTS, (False, True),
            ("fragment", "compute")):
        if (newton and (mode != "exact" or spp == 1)) or (pieces and mode == "fast"):
            continue
        opts = Render(mode=mode, precision=precision, samples_per_pixel=spp,
                      subsamples="newton" if newton else "mapped")
        yield plan(opts, True, fp64, fx, *cams, pieces=pieces, stage=stage, quantize=quantize)


def _programs(entry: str) -> str:
    return " → ".join(f"`{f}`" for f in (*PROGRAMS.get(entry, ()), entry))


def _in_order(names, after: dict) -> list:
    """``names`` so that each comes after those that precede it in some plan (``after``: name →
    its predecessors), the first seen first among those free to go."""
    done: list = []
    while len(done) < len(names):
        done.append(next(n for n in names if n not in done and after.get(n, set()) <= set(done)))
    return done


def markdown() -> str:
    """Two tables: every pass of a plan (its program, when it runs, its stage, its variants),
    and which of the plan's defines each deformation pass is compiled with."""
    passes, defines, after = {}, {}, {}
    for p in plans():
        firsts = list(dict.fromkeys(ps.shader for ps in p.passes))
        for a, b in zip(firsts, firsts[1:]):
            after.setdefault(b, set()).add(a)
        for ps in p.passes:
            row = passes.setdefault(ps.shader, {"steps": [], "when": set(), "stages": set(), "variants": []})
            if ps.step not in row["steps"]:
                row["steps"].append(ps.step)
            if ps.when:
                row["when"].add(ps.when)
            row["stages"].add(p.stage)
            if ps.variant and ps.variant not in row["variants"]:
                row["variants"].append(ps.variant)
            if ps.step in DEFORM_STEPS:
                defines.setdefault(ps.shader, set()).update(p.define_dict)
    out = ["| pass (entry file) | program | step | runs | pixel stage | variants (#define) |",
           "|---|---|---|---|---|---|"]
    for entry in _in_order(passes, after):
        row = passes[entry]
        stages = "both" if len(row["stages"]) == 2 else row["stages"].pop()
        out.append(f"| `{entry}` | {_programs(entry)} | {', '.join(row['steps'])} | "
                   f"{', '.join(sorted(row['when'])) or 'always'} | {stages} | "
                   f"{', '.join(f'`{v}`' for v in row['variants']) or '—'} |")
    names = sorted(set().union(*defines.values()))
    out += ["", "| #define | " + " | ".join(f"`{e}`" for e in defines) + " |",
            "|---|" + "---|" * len(defines)]
    for name in names:
        out.append(f"| `{name}` | " + " | ".join("•" if name in d else "" for d in defines.values()) + " |")
    return "\n".join(out) + "\n"


if __name__ == "__main__":
    print(markdown(), end="")
