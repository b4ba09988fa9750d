"""A reduced version of the paper's §4 calibration studies that runs in minutes on 2 cores.

    .venv/bin/python examples/calib_study.py [WORK_DIR] [--results bench/results/calib_study] [-j 2]

Renders into WORK_DIR, at a quarter of the paper's image size (406×308 px, Table 8 rig scaled)
and with Table 8's 2 % sensor noise, libraries of a perfect 9×9 target over the full field of
view and at its centre only, and of targets with dot scatter σ = 0.05 and 0.10 mm, three
printed targets (target seeds) per σ; then the three studies (number of pairs, FOV, target
quality) with fewer Monte-Carlo runs than the paper's, their figures and summary tables into
--results. The quality study's runs go round the targets of each σ, so its spread is over
targets, not one pattern's fixed error. Everything is resumable: run it again and finished
libraries and calibrations are kept. The full-size, full-count version is the same calls with
paper_rig(1.0), 1000 pairs and the Table 6 run counts (`glsim calib library default --pairs 1000 …`).
"""
import argparse
import time
from pathlib import Path

from glsim.scene import Noise
from glsim.workflows.calib import library
from glsim.workflows.calib import study
from glsim.workflows.calib.poses import PoseSpec
from glsim.workflows.calib.targets import Defects, DotGrid

SCALE = 0.25
NOISE = Noise(sigma=2.0)      # Table 8 (and `glsim calib library`'s default)
RESULTS = Path(__file__).resolve().parent.parent / "bench" / "results" / "calib_study"
LIBRARIES = {   # name: (pairs, pose FOV, dot scatter σ mm, target seed)
    "full": (60, "full", 0.0, 0),
    "centre": (30, "centre", 0.0, 0),
    **{f"sigma{s:.2f}-t{t}": (30, "full", s, t) for s in (0.05, 0.10) for t in (1, 2, 3)},
}
STUDIES = {     # study: (libraries, sizes, runs per size)
    "images": (["full"], (10, 20, 40), (30, 30, 20)),
    "fov": (["full", "centre"], (10, 25), (20, 20)),
    "quality": (["full"] + [n for n in LIBRARIES if n.startswith("sigma")], (25,), (30,)),
}


def progress(what):
    t0 = time.perf_counter()

    def report(done, total):
        print(f"\r  {what} {done}/{total} ({time.perf_counter() - t0:.0f} s)", end="\n" if done == total else "",
              flush=True)
    return report


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("work", nargs="?", default="calib-study", help="where the libraries are rendered")
    p.add_argument("--results", default=str(RESULTS), help="where the study CSVs, figures and summaries go")
    p.add_argument("--processes", "-j", type=int, default=2)
    a = p.parse_args()
    work, results = Path(a.work), Path(a.results)
    results.mkdir(parents=True, exist_ok=True)
    rig = library.paper_rig(SCALE)
    for name, (n, fov, sigma, target_seed) in LIBRARIES.items():
        print(f"library {name}: {n} pairs, FOV {fov}, σ = {sigma} mm, target seed {target_seed}")
        target = DotGrid(defects=Defects(sigma=sigma, seed=target_seed))
        library.write_library(rig, target, n, work / name, seed=11, spec=PoseSpec(fov=fov), noise=NOISE,
                              progress=progress("pairs"), workers=a.processes)
    for name, (libs, sizes, runs) in STUDIES.items():
        print(f"study {name}: sizes {sizes}, runs {runs}")
        rows = study.run_study(name, [work / lib for lib in libs], results / f"study_{name}.csv", sizes, runs, seed=3,
                               processes=a.processes, progress=progress("calibrations"))
        figs = study.figures(name, rows, results)
        study.write_summary(results / f"summary_{name}.md", rows)
        print(f"  {len(rows)} calibrations; {', '.join(f.name for f in figs)}")


if __name__ == "__main__":
    main()
