"""Monte-Carlo calibration studies on libraries (the paper's §4): many calibrations on random
balanced subsets of pairs, one CSV row per calibration, and figures like Figs 11–13, 15, 16.

Studies
    ``images``   one library; subsets of each size in ``sizes`` (Table 6: 10 … 250 pairs),
                 ``runs`` calibrations each → spread of the parameters against the number
                 of pairs (Fig. 11) and their covariance (Fig. 12).
    ``fov``      libraries made with PoseSpec(fov="full") and fov="centre" → the k1 error
                 (Fig. 13) and epipolar distances (Fig. 14, Table 7) of both.
    ``quality``  libraries per target quality (Defects.sigma) → RMS (Fig. 15) and the
                 spread of the parameters (Fig. 16) against sigma.

Several libraries may share a label (fov, quality): e.g. one per ``--target-seed`` at each σ.
Run r of a label then calibrates a subset of its libraries' r mod m-th (sorted by target seed,
then directory), so the runs of a label go round its targets: the mean and spread over runs
are over targets too, not one printed pattern's fixed error (column ``target_seed``). A
calibration always uses one library (one printed target).

A subset of n pairs is drawn from *all* pairs of the library (bad ones included, as the
paper's Fig. 11), balanced over the motion kinds (n/K of each, the remainder at random);
pairs that are not detected are then left out (column ``n_used``). The settings go to a .json beside the CSV. Run r of size n uses the
seed (study seed, library label, n, r), so rows are reproducible and independent of the
order and the number of processes. The CSV is appended row by row; a rerun skips the rows it
holds (an interrupted line is dropped), so a study can be stopped and resumed.
"""
from __future__ import annotations

import csv
import hashlib
import json
import math
import multiprocessing as mp
import time
from pathlib import Path

import numpy as np

from glsim.io import images as io
from glsim.errors import SceneError
from glsim.workflows.calib import calibrate as cal
from glsim.workflows.calib import library as libmod

STUDIES = ("images", "fov", "quality")
TABLE6 = ((10, 1000), (25, 1000), (50, 1000), (75, 250), (100, 250), (250, 250))
PARAMS = [f"{p}{i}" for i in (1, 2) for p in ("fx", "fy", "cx", "cy")] + \
    [f"{p}_{i}" for i in (1, 2) for p in ("k1", "k2", "p1", "p2", "k3")] + \
    ["Tx", "Ty", "Tz", "Theta", "Phi", "Psi"]
COLUMNS = ["label", "sigma", "target_seed", "n", "run", "n_used", "rms", "rms1", "rms2"] + PARAMS + \
    [f"err_{p}" for p in PARAMS] + ["err_T_norm", "err_rotation_deg", "epipolar_max_px", "seconds"]
KEY = ("label", "n", "run")


def label_of(study: str, lib: libmod.Library) -> str:
    """A library's label in a study: its pose FOV (fov), its target sigma (quality) or 'all'."""
    if study == "fov":
        return lib.manifest["poses"]["fov"]
    if study == "quality":
        return f"{lib.target.defects.sigma:g}"
    return "all"


def balanced_subset(kinds: list[str], n: int, rng: np.random.Generator) -> list[int]:
    """n indices into ``kinds``: ⌊n/K⌋ of each kind, the remainder from kinds drawn at random
    (without replacement throughout)."""
    if n > len(kinds):
        raise SceneError("sizes", f"{n} pairs asked, the library has {len(kinds)}",
                         "ask for at most as many pairs as the library holds")
    groups = {k: list(rng.permutation([i for i, x in enumerate(kinds) if x == k])) for k in sorted(set(kinds))}
    take = {k: min(n // len(groups), len(g)) for k, g in groups.items()}
    chosen = [i for k, g in groups.items() for i in g[:take[k]]]
    rest = [i for k, g in groups.items() for i in g[take[k]:]]
    chosen += list(rng.permutation(rest)[:n - len(chosen)])
    return sorted(int(i) for i in chosen)


def run_seed(seed: int, label: str, n: int, run: int) -> int:
    digest = hashlib.sha256(f"{seed}/{label}/{n}/{run}".encode()).digest()
    return int.from_bytes(digest[:8], "little")


def read_rows(path: Path) -> list[dict]:
    """The complete rows of a study CSV (a truncated or malformed last line is dropped)."""
    if not path.is_file():
        return []
    rows = []
    with open(path, newline="") as f:
        for row in csv.DictReader(f):
            if list(row) != COLUMNS or any(v is None for v in row.values()):
                continue
            try:
                [float(row[c]) for c in COLUMNS if c != "label"]
            except ValueError:
                continue
            rows.append(row)
    return rows


# --- the worker side ----------------------------------------------------------------------------

_STATE: dict = {}


def _init(libraries: dict, detections: dict, model: str, min_points: int, bias_iterations: int) -> None:
    """``libraries``/``detections`` keyed by (label, index in the label's group)."""
    _STATE.update(libraries={k: libmod.load_library(d) for k, d in libraries.items()},
                  detections=detections, model=model, min_points=min_points, bias_iterations=bias_iterations)


def _calibrate_task(task) -> dict:
    label, n, run, seed = task
    group = sorted(k for k in _STATE["libraries"] if k[0] == label)
    key = group[run % len(group)]
    lib, dets = _STATE["libraries"][key], _STATE["detections"][key]
    t0 = time.perf_counter()
    rng = np.random.default_rng(run_seed(seed, label, n, run))
    chosen = balanced_subset([p["kind"] for p in lib.pairs], n, rng)
    defects = getattr(lib.target, "defects", None)
    row = {"label": label, "sigma": defects.sigma if defects else 0.0, "target_seed": defects.seed if defects else 0,
           "n": n, "run": run}
    try:
        c = cal.calibrate_pairs(lib, dets, [lib.pairs[i]["pair"] for i in chosen], _STATE["model"],
                                _STATE["min_points"], _STATE["bias_iterations"])
    except SceneError:  # fewer than 3 usable pairs: recorded as a failed calibration
        return {**row, "n_used": 0, **{k: math.nan for k in COLUMNS if k not in row and k != "n_used"}}
    est = cal.parameters(c.K1, c.D1, c.K2, c.D2, c.R, c.T)
    err = cal.errors(c, *lib.cameras)
    _, _, d = cal.epipolar_map(c, *lib.cameras, step=max(lib.cameras[0].width // 50, 1))
    row.update(n_used=len(c.pairs), rms=c.rms, rms1=c.rms1, rms2=c.rms2, **{p: est[p] for p in PARAMS},
               **{f"err_{p}": err[p] for p in PARAMS}, err_T_norm=err["T_norm"],
               err_rotation_deg=err["rotation_deg"], epipolar_max_px=float(np.nanmax(d)),
               seconds=time.perf_counter() - t0)
    return row


# --- the study ----------------------------------------------------------------------------------

def run_study(study: str, library_dirs, out_csv, sizes=None, runs=None, seed: int = 0,
              model: str = "k1k2p1p2k3", min_points: int | None = None, bias_iterations: int = 1,
              processes: int = 1, progress=None) -> list[dict]:
    """Run (or resume) a study and return all its rows. ``sizes``/``runs``: pairs per
    calibration and calibrations per size (default Table 6, capped at the library size).
    ``progress(done, total)`` is called after every calibration."""
    if study not in STUDIES:
        raise SceneError("study", f"{study!r} is not one of {STUDIES}", f"use one of {', '.join(STUDIES)}")
    groups: dict[str, list] = {}
    for d in library_dirs:
        lib = libmod.load_library(d)
        groups.setdefault(label_of(study, lib), []).append(lib)
    if study == "images" and (len(groups) != 1 or len(next(iter(groups.values()))) != 1):
        raise SceneError("libraries", f"the images study takes one library, got {len(list(library_dirs))}", "give one")
    libs = {}
    for label, group in groups.items():
        group.sort(key=lambda lib: (getattr(getattr(lib.target, "defects", None), "seed", 0), str(lib.directory)))
        seeds = [(getattr(getattr(lib.target, "defects", None), "seed", 0), lib.manifest["seed"]) for lib in group]
        if len(set(seeds)) != len(seeds):
            raise SceneError("libraries", f"libraries of label {label!r} in the {study} study repeat a target seed and "
                             "library seed", "give each its own --target-seed (a printed target) or --seed (poses)")
        libs.update({(label, i): lib for i, lib in enumerate(group)})
    smallest = min(len(lib.pairs) for lib in libs.values())
    if sizes is None:
        table = [(n, r) for n, r in TABLE6 if n <= smallest]
        if not table:
            raise SceneError("sizes", f"the smallest library has {smallest} pairs, Table 6 starts at 10",
                             "give the subset sizes (--sizes)")
        sizes, default_runs = zip(*table)
        runs = runs or default_runs
    runs = list(runs) if runs is not None else [TABLE6[0][1]] * len(sizes)
    if len(runs) == 1:
        runs = runs * len(sizes)
    if len(runs) != len(sizes):
        raise SceneError("runs", f"{len(runs)} run counts for {len(sizes)} sizes", "give one per size, or one for all")
    min_points = min_points or cal.default_min_points(next(iter(libs.values())).target)
    detections = {label: cal.detect_library(lib, min_points, processes) for label, lib in libs.items()}

    path = Path(out_csv)
    settings = {"study": study, "libraries": sorted(str(lib.directory.resolve()) for lib in libs.values()),
                "seed": seed, "model": model, "min_points": min_points, "bias_iterations": bias_iterations}
    sidecar = path.with_suffix(".json")
    if path.is_file() and sidecar.is_file() and json.loads(sidecar.read_text()) != settings:
        raise SceneError(str(path), "belongs to a study with other settings (see its .json)",
                         "write to another file, or remove the old study")
    io.write_text(sidecar, json.dumps(settings, indent=1))
    rows = read_rows(path)
    done = {tuple(str(r[k]) for k in KEY) for r in rows}
    tasks = [(label, int(n), r, seed) for label in groups for n, nr in zip(sizes, runs) for r in range(nr)
             if (label, str(n), str(r)) not in done]
    with io.atomic_path(path) as tmp:          # rewrite the complete rows, then append
        with open(tmp, "w", newline="") as f:
            w = csv.DictWriter(f, COLUMNS)
            w.writeheader()
            w.writerows(rows)
    init = ({k: str(v.directory) for k, v in libs.items()}, detections, model, min_points, bias_iterations)
    with open(path, "a", newline="") as f:
        w = csv.DictWriter(f, COLUMNS)
        results = _map(tasks, init, processes)
        for k, row in enumerate(results, 1):
            w.writerow(row)
            f.flush()
            rows.append({c: str(row[c]) for c in COLUMNS})
            if progress:
                progress(k, len(tasks))
    return rows


def _map(tasks, init, processes: int):
    if processes <= 1 or len(tasks) <= 1:
        _init(*init)
        yield from map(_calibrate_task, tasks)
        return
    with mp.get_context("spawn").Pool(processes, initializer=_init, initargs=init) as pool:
        yield from pool.imap_unordered(_calibrate_task, tasks, chunksize=1)


# --- figures --------------------------------------------------------------------------------------

def _table(rows: list[dict]) -> dict[str, np.ndarray]:
    return {c: np.array([r[c] for r in rows], dtype=object if c == "label" else float) for c in COLUMNS}


def _save(fig, path: Path) -> Path:
    with io.atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110)
    cal.pyplot().close(fig)
    return path


FIG11 = (("fx1", "Fx cam 1 [px]"), ("k1_1", "κ1 cam 1"), ("p2_1", "P2 cam 1"), ("cx1", "Cx cam 1 [px]"),
         ("Tz", "Tz [mm]"), ("Phi", "Ry (Phi) [deg]"))
FIG12 = ("fx1", "fy1", "cx1", "cy1", "k1_1", "k2_1", "Tz", "Phi")


def figures(study: str, rows: list[dict], out_dir) -> list[Path]:
    """The study's figures as PNGs in ``out_dir`` (matplotlib)."""
    plt = cal.pyplot()
    out = Path(out_dir)
    t = _table([r for r in rows if float(r["n_used"]) > 0])
    written = []
    if study == "images":
        ns = sorted(set(t["n"]))
        fig, axes = plt.subplots(2, 3, figsize=(12, 6.5), layout="constrained")
        for ax, (p, name) in zip(axes.ravel(), FIG11):
            ax.plot(ns, [np.std(t[p][t["n"] == n], ddof=1) for n in ns], "o-")
            ax.set(xlabel="calibration pairs", ylabel=f"std {name}", xscale="log")
            ax.set_xticks(ns, [f"{n:g}" for n in ns], minor=False)
            ax.minorticks_off()
            ax.grid(alpha=0.3)
        fig.suptitle("Spread of the calibration parameters against the number of pairs (cf. Fig. 11)")
        written.append(_save(fig, out / "fig11_images.png"))
        n = max(ns, key=lambda k: (np.sum(t["n"] == k) >= 10, -abs(k - 50)))
        sel = t["n"] == n
        fig, axes = plt.subplots(len(FIG12), len(FIG12), figsize=(13, 13))
        for i, a in enumerate(FIG12):
            for j, b in enumerate(FIG12):
                ax = axes[i, j]
                if i == j:
                    ax.hist(t[a][sel], bins=20)
                else:
                    ax.plot(t[b][sel], t[a][sel], ".", ms=2)
                ax.set_xticks([]), ax.set_yticks([])
                if i == len(FIG12) - 1:
                    ax.set_xlabel(b)
                if j == 0:
                    ax.set_ylabel(a)
        fig.suptitle(f"Covariance of the calibration parameters, {n} pairs (cf. Fig. 12)")
        written.append(_save(fig, out / "fig12_covariance.png"))
    elif study == "fov":
        labels, ns = sorted(set(t["label"])), sorted(set(t["n"]))
        fig, axes = plt.subplots(1, 2, figsize=(11, 4.5), layout="constrained")
        for ax, cam in zip(axes, (1, 2)):
            data = [np.abs(t[f"err_k1_{cam}"][(t["label"] == lab) & (t["n"] == n)]) for lab in labels for n in ns]
            ax.boxplot(data, tick_labels=[f"{lab}\n{n:g} pairs" for lab in labels for n in ns])
            ax.set(ylabel=f"|κ1 error| camera {cam}", yscale="log")
        fig.suptitle("Accuracy of κ1: full field of view against centre only (cf. Fig. 13)")
        written.append(_save(fig, out / "fig13_fov.png"))
    elif study == "quality":
        sig = sorted(set(t["sigma"]))
        fig, ax = plt.subplots(figsize=(6, 4.5), layout="constrained")
        ax.boxplot([t["rms"][t["sigma"] == s] for s in sig], tick_labels=[f"{s:g}" for s in sig])
        ax.set(xlabel="target dot scatter σ [mm]", ylabel="reprojection RMS [px]")
        fig.suptitle("Calibration score against target quality (cf. Fig. 15)")
        written.append(_save(fig, out / "fig15_quality_rms.png"))
        fig, axes = plt.subplots(2, 3, figsize=(12, 6.5), layout="constrained")
        for ax, (p, name) in zip(axes.ravel(), FIG11):
            e = [t[f"err_{p}"][t["sigma"] == s] for s in sig]
            ax.errorbar(sig, [np.mean(x) for x in e], yerr=[np.std(x, ddof=1) if len(x) > 1 else 0 for x in e],
                        fmt="o-", capsize=3)
            ax.axhline(0, color="k", lw=0.5)
            ax.set(xlabel="σ [mm]", ylabel=f"error {name}")
        fig.suptitle("Calibration errors (mean ± std) against target quality (cf. Fig. 16)")
        written.append(_save(fig, out / "fig16_quality_params.png"))
    return written


def summary(rows: list[dict]) -> list[dict]:
    """Per (label, n): count, mean RMS, and mean/std of the key errors — for the study's
    markdown table."""
    t = _table([r for r in rows if float(r["n_used"]) > 0])
    out = []
    for label in sorted(set(t["label"])):
        for n in sorted(set(t["n"][t["label"] == label])):
            s = (t["label"] == label) & (t["n"] == n)
            entry = {"label": label, "n": int(n), "runs": int(s.sum()), "rms": float(np.mean(t["rms"][s])),
                     "epipolar_max_px": float(np.max(t["epipolar_max_px"][s]))}
            for p in ("fx1", "cx1", "k1_1", "k2_1", "k3_1", "k1_2", "k2_2", "k3_2", "Tz", "Phi"):
                entry[f"mean_err_{p}"] = float(np.mean(t[f"err_{p}"][s]))
                entry[f"std_{p}"] = float(np.std(t[p][s], ddof=1)) if s.sum() > 1 else math.nan
            out.append(entry)
    return out


def write_summary(path, rows: list[dict]) -> Path:
    """The summary as a markdown table."""
    s = summary(rows)
    if not s:
        return io.write_text(path, "no successful calibrations\n")
    cols = list(s[0])
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    lines += ["| " + " | ".join(f"{e[c]:.4g}" if isinstance(e[c], float) else str(e[c]) for c in cols) + " |"
              for e in s]
    return io.write_text(path, "\n".join(lines) + "\n")
