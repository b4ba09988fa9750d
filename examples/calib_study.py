"""A reduced version of the paper's §4 calibration studies that runs in minutes on 2 cores.

    .venv/bin/python examples/calib_study.py [OUT_DIR] [--processes 2]

Renders, at a quarter of the paper's image size (406×308 px, Table 8 rig scaled), libraries of
a perfect 9×9 target over the full field of view and at its centre only, and of targets with
dot scatter σ = 0.05 and 0.10 mm; then the three studies (number of pairs, FOV, target
quality) with fewer Monte-Carlo runs than the paper's, their figures and summary tables.
Everything is resumable: run it again and finished libraries and calibrations are kept.
The full-size, full-count version is the same calls with paper_rig(1.0), 1000 pairs and
the Table 6 run counts (`glsim calib library default --pairs 1000 …`).
"""
import argparse
import time
from pathlib import Path

from glsim.workflows.calib import library
from glsim.workflows.calib import study
from glsim.workflows.calib.poses import PoseSpec
from glsim.workflows.calib.targets import Defects, DotGrid

SCALE = 0.25
LIBRARIES = {   # name: (pairs, pose FOV, dot scatter σ mm)
    "full": (60, "full", 0.0),
    "centre": (30, "centre", 0.0),
    "sigma0.05": (30, "full", 0.05),
    "sigma0.10": (30, "full", 0.10),
}
STUDIES = {     # study: (libraries, sizes, runs per size)
    "images": (["full"], (10, 20, 40), (30, 30, 20)),
    "fov": (["full", "centre"], (10, 25), (20, 20)),
    "quality": (["full", "sigma0.05", "sigma0.10"], (25,), (20,)),
}


def progress(what):
    t0 = time.perf_counter()

    def report(done, total):
        print(f"\r  {what} {done}/{total} ({time.perf_counter() - t0:.0f} s)", end="\n" if done == total else "",
              flush=True)
    return report


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("out", nargs="?", default="calib-study")
    p.add_argument("--processes", "-j", type=int, default=2)
    a = p.parse_args()
    out = Path(a.out)
    rig = library.paper_rig(SCALE)
    for name, (n, fov, sigma) in LIBRARIES.items():
        print(f"library {name}: {n} pairs, FOV {fov}, σ = {sigma} mm")
        target = DotGrid(defects=Defects(sigma=sigma, seed=1))
        library.write_library(rig, target, n, out / name, seed=11, spec=PoseSpec(fov=fov),
                              progress=progress("pairs"))
    for name, (libs, sizes, runs) in STUDIES.items():
        print(f"study {name}: sizes {sizes}, runs {runs}")
        rows = study.run_study(name, [out / lib for lib in libs], out / f"study_{name}.csv", sizes, runs, seed=3,
                               processes=a.processes, progress=progress("calibrations"))
        figs = study.figures(name, rows, out)
        study.write_summary(out / f"summary_{name}.md", rows)
        print(f"  {len(rows)} calibrations; {', '.join(f.name for f in figs)}")


if __name__ == "__main__":
    main()
