"""Command line: a thin layer over the Python API (glsim.render, glsim.scene)."""
from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

from glsim.errors import GlsimError, SceneError, interrupted
from glsim.limits import MAX_IMAGE_SIDE, MAX_STEPS, parse_steps
from glsim.scene import BACKENDS, MODES, bulge_scene, demo_effects, load_scene


def _count(n: int, noun: str) -> str:
    """``n`` and ``noun``, plural unless n is 1 ("1 image", "3 images")."""
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


def _progress(done: int, total: int, path: str) -> None:
    width = 30
    bar = "#" * (width * done // total) + "." * (width - width * done // total)
    sys.stderr.write(f"\r[{bar}] {done}/{total} {Path(path).name}   ")
    if done == total:
        sys.stderr.write("\n")
    sys.stderr.flush()


def _steps(text: str | None):
    """'0,2,5' or '0-3' → list of ints (None = every step)."""
    return None if text is None else parse_steps(text, "--steps")


def _overrides(scene, args):
    render = {k: v for k, v in (("backend", args.backend), ("mode", args.mode)) if v}
    return scene.replace(render=render) if render else scene


def _run(scene, out: str, args, label: str) -> int:
    from glsim.workflows.sequence import write_sequence

    t0 = time.perf_counter()
    w = write_sequence(scene, out, steps=_steps(args.steps), backend=args.backend,
                       truth=args.truth, progress=None if args.quiet else _progress,
                       truth_format=args.truth_format, force=args.force)
    total = time.perf_counter() - t0
    n = len(w.images)
    r = scene.render
    if w.removed:
        print(f"--force: removed {_count(len(w.removed), 'image')} and truth files of the earlier render in {out}/")
    if w.swept:
        print(f"resumed: removed {_count(len(w.swept), 'temporary file')} an interrupted run left in {out}/")
    if w.kept:
        print(f"resumed: kept {_count(len(w.kept), 'image')} (with their truth) already rendered in {out}/ "
              f"from the same scene, their bytes those recorded in render-manifest.jsonl")
    if w.redone:
        shown = "; ".join(w.redone[:3]) + ("; …" if len(w.redone) > 3 else "")
        print(f"resumed: rendered {_count(len(w.redone), 'image')} again whose files there did not match "
              f"render-manifest.jsonl ({shown})")
    print(f"{label}: wrote {_count(n, 'image')} ({_count(len(w.truth), 'truth file')}) to {out}/ in {total:.2f} s "
          f"(render {sum(w.seconds):.2f} s, {sum(w.seconds) / max(n, 1) * 1e3:.0f} ms per image; "
          f"backend={args.backend or r.backend}, mode={r.mode}, interpolation={r.interpolation}, "
          f"spp={r.samples_per_pixel})")
    if max(w.saturated, default=0.0) > 0:
        print(f"saturated (clipped) pixels: up to {100 * max(w.saturated):.3g} % of an image's specimen pixels")
    print(f"resolved scene: {w.scene_json}")
    return 0


def cmd_info(args) -> int:
    from glsim.backends.gl.context import gl_context, info

    with gl_context() as ctx:
        for key, value in info(ctx, probe=True).items():
            print(f"{key:17s} {value}")
    return 0


def cmd_demo(args) -> int:
    if not all(1 <= n <= MAX_IMAGE_SIDE for n in args.size):
        raise SceneError("--size", f"must be two image sides of 1…{MAX_IMAGE_SIDE} px, got "
                         f"{args.size[0]} {args.size[1]}", "e.g. --size 1624 1234")
    if not 1 <= args.n_steps < MAX_STEPS:
        raise SceneError("--n-steps", f"must be 1…{MAX_STEPS - 1} load steps, got {args.n_steps}", "e.g. --n-steps 3")
    scene = _overrides(bulge_scene(size=tuple(args.size), steps=args.n_steps), args)
    label = "glsim demo (bulge test, paper Tables 2-3"
    if args.effects:
        scene = demo_effects(scene)
        label += "; spotlight, f/2 depth of field, 2 % noise"
    return _run(scene, args.output, args, label + ")")


def cmd_render(args) -> int:
    scene = _overrides(load_scene(args.scene), args)
    out = args.output or str(scene.resolve(scene.output.directory))
    return _run(scene, out, args, f"glsim render {args.scene}")


def _rig_cameras(source: Path, names, size):
    """The two cameras of a scene file, a calibration result folder or a rig file in any format."""
    from glsim.io.calibfiles import import_rig

    if source.is_dir():
        found = [source / n for n in ("calibration.yaml", "rig.yaml") if (source / n).is_file()]
        if not found:
            raise GlsimError(f"{source}: holds no calibration.yaml (glsim calib run) or rig.yaml (glsim calib "
                             "library); give a scene file, such a folder or a rig file")
        return import_rig(found[0], "opencv")
    if source.suffix in (".toml", ".json") and source.name != "calibration.json":
        scene = load_scene(source)
        if len(scene.cameras) < 2:
            raise GlsimError(f"{source}: the scene has {len(scene.cameras)} camera; a rig needs two")
        a, b = (int(n) if str(n).isdigit() else n for n in names)
        return scene.camera(a), scene.camera(b)
    return import_rig(source, image_size=size)


def cmd_rig_export(args) -> int:
    from glsim.io.calibfiles import export_rig

    a, b = _rig_cameras(Path(args.source), args.cameras, args.size)
    path = export_rig(args.output, a, b, args.format)
    print(f"glsim rig export: wrote {path} ({args.format or path.suffix[1:]}; camera 0 = {a.name}, "
          f"camera 1 = {b.name})")
    return 0


def cmd_compare(args) -> int:
    from glsim.workflows.compare import run

    res = run(args.result, args.truth, args.step, args.output)
    print(res["markdown"], end="")
    print(f"glsim compare: wrote compare.json, compare.md and compare.png to {res['out']}/")
    return 0


def cmd_jacobian(args) -> int:
    from glsim.workflows.jacobian import camera_arg, jacobian

    res = jacobian(_overrides(load_scene(args.scene), args), camera_arg(args.camera), args.step, args.output,
                   args.backend, args.rig)
    J = res.jacobian
    print(f"glsim jacobian: wrote {args.output} ({J.shape[0]} pixels × {J.shape[1]} displacement components, "
          f"{J.nnz} non-zeros; camera {res.camera.name}, step {res.step}, backend={res.backend}, "
          f"mode={res.options.mode}, spp={res.options.samples_per_pixel})")
    return 0


def _delegated(name: str, argv: list[str]) -> int:
    """`glsim bench|calib|check|design|library|preview|verify …`: their own argument parsers take the rest of the line."""
    if name == "bench":
        from glsim.bench.cli import main as run
    elif name == "calib":
        from glsim.workflows.calib.cli import main as run
    elif name == "check":
        from glsim.check.runner import main as run
    elif name == "library":
        from glsim.workflows.library.cli import main as run
    elif name == "preview":
        from glsim.workflows.preview.cli import main as run
    elif name == "design":
        from glsim.workflows.design.cli import main as run
    else:
        from glsim.dic.cli import main as run
    return run(argv)


DELEGATED = {"bench": "benchmarks: glsim bench {accuracy,effects,library,preview,scaling,quadratic,peer,throughput,jacobian,training} …",
             "calib": "calibration targets: glsim calib {library,run,study} …",
             "verify": "independent stereo-DIC verification: glsim verify run …",
             "preview": "interactive preview window: glsim preview SCENE.toml [--screenshot out.png]",
             "check": "GL against the oracle and closed forms on this machine's driver: glsim check [--json F] [--skip TEXT]",
             "library": "image libraries from a spec: glsim library SPEC.toml -o DIR [--workers N] …",
             "design": "what will my DIC measure? set-ups × DIC settings → error maps, ranking: glsim design SPEC.toml -o DIR"}


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--backend", choices=BACKENDS, help="override [render] backend")
    p.add_argument("--mode", choices=MODES, help="override [render] mode")
    p.add_argument("--steps", help="load steps to render, e.g. 0,2 or 0-3 (default: all)")
    p.add_argument("--truth", action="store_true", help="also write per-pixel ground truth")
    p.add_argument("--truth-format", choices=("npz", "tiff", "tiff64", "vtk"), default="npz",
                   help="one .npz per image (float64), or one TIFF per map: tiff stores float32 "
                        "(a coordinate of 256–512 mm within 1.5e-5 mm, a displacement within 3.1e-5 mm; "
                        "twice both at 512–1024 mm), tiff64 float64; vtk: one ParaView .vti per image "
                        "and the FE mesh as mesh.pvd (float64)")
    p.add_argument("--force", action="store_true",
                   help="replace a render of another scene in the output directory (its images and "
                        "truth are removed first); without it such a directory is refused, and one "
                        "holding the same scene is resumed")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="glsim", description=__doc__)
    sub = ap.add_subparsers(dest="command", required=True)
    sub.add_parser("info", help="GL vendor, renderer, version, EGL device, limits, fp64").set_defaults(func=cmd_info)
    d = sub.add_parser("demo", help="render the built-in bulge scene (stereo, a few steps)")
    d.add_argument("-o", "--output", default="glsim-demo")
    d.add_argument("--n-steps", type=int, default=3, help="load steps after the reference state")
    d.add_argument("--size", type=int, nargs=2, default=(1624, 1234), metavar=("W", "H"),
                   help="image size in px (the rig scales with it)")
    d.add_argument("--effects", action="store_true",
                   help="lit, slightly defocused and noisy variant (paper §2.2)")
    _common(d)
    d.set_defaults(func=cmd_demo)
    r = sub.add_parser("render", help="render a scene file")
    r.add_argument("scene")
    r.add_argument("-o", "--output", help="output directory (default: [output] directory)")
    _common(r)
    r.set_defaults(func=cmd_render)
    j = sub.add_parser("jacobian", help="an image's derivative w.r.t. the nodal displacements, as a sparse .npz")
    j.add_argument("scene")
    j.add_argument("--camera", default="0", help="camera name or index (default 0)")
    j.add_argument("--step", type=int, required=True, help="load step")
    j.add_argument("-o", "--output", required=True, help=".npz file to write (scipy.sparse.load_npz reads it)")
    j.add_argument("--backend", choices=BACKENDS, help="override [render] backend")
    j.add_argument("--mode", choices=MODES, help="override [render] mode")
    j.add_argument("--rig", action="store_true", help="also the derivative w.r.t. the camera's pose, intrinsics and "
                   "distortion (rig_data, rig_indices, rig_indptr, rig_columns)")
    j.set_defaults(func=cmd_jacobian)
    from glsim.io.calibfiles import FORMATS

    rig = sub.add_parser("rig", help="stereo rig files for DIC packages").add_subparsers(dest="rig", required=True)
    x = rig.add_parser("export", help="write a scene's true rig, a calibrated rig or a rig file in another format")
    x.add_argument("source", help="scene (.toml / scene.json), glsim calib output folder, or rig file "
                                  f"({', '.join(f'{f} {e}' for f, e in FORMATS.items())})")
    x.add_argument("--format", choices=tuple(FORMATS), help="output format (default: from -o's extension)")
    x.add_argument("-o", "--output", required=True, help="file to write")
    x.add_argument("--cameras", nargs=2, default=(0, 1), metavar=("A", "B"),
                   help="the scene's cameras for camera 0 and 1 (names or indices; default the first two)")
    x.add_argument("--size", type=int, nargs=2, metavar=("W", "H"), help="image size for a MatchID source")
    x.set_defaults(func=cmd_rig_export)
    c = sub.add_parser("compare", help="a DIC result (CSV or verify's .npz) against the ground truth of a render")
    c.add_argument("result", help="CSV with u, v (camera 0 reference px) and X, Y, Z and/or U, V, W (mm)")
    c.add_argument("--truth", required=True, help="the render's output folder (its scene.json)")
    c.add_argument("--step", type=int, required=True, help="the load step the DIC result measured")
    c.add_argument("-o", "--output", help="where compare.{json,md,png} go (default: RESULT's folder/compare)")
    c.set_defaults(func=cmd_compare)
    for name, text in DELEGATED.items():  # listed for --help; main() hands them their arguments
        sub.add_parser(name, help=text)
    return ap


def _format_warning(message, category, filename, lineno, line=None) -> str:
    """Warnings on the command line: one line with the message, no source location or line."""
    kind = "" if category.__module__.startswith("glsim") or category is UserWarning else f" ({category.__name__})"
    return f"glsim: warning{kind}: {message}\n"


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    formatwarning, warnings.formatwarning = warnings.formatwarning, _format_warning
    try:
        from glsim.backends.gl.plan import environment_stage

        environment_stage()   # a bad GLSIM_PIXEL_STAGE is refused before a command writes anything
        if argv and argv[0] in DELEGATED:
            return _delegated(argv[0], argv[1:])
        args = parser().parse_args(argv)
        return args.func(args)
    except GlsimError as exc:
        print(f"glsim: error: {exc}", file=sys.stderr)
        return 2
    except BaseException as exc:
        if not interrupted(exc):
            raise
        print("glsim: interrupted (no partial files were left; run the same command again to resume)",
              file=sys.stderr)
        return 130
    finally:
        warnings.formatwarning = formatwarning


if __name__ == "__main__":
    sys.exit(main())
