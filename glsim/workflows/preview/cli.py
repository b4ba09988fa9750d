"""``glsim preview SCENE [--screenshot out.png] …``."""
from __future__ import annotations

import argparse

from glsim.errors import GlsimError
from glsim.scene import load_scene
from glsim.workflows.preview.controls import OVERLAYS


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="glsim preview", description="Interactive preview of a scene: both cameras "
                                 "as they will record, the 3-D rig, overlays and live controls (docs/preview.md).")
    ap.add_argument("scene", help="scene file (TOML, or a scene.json glsim wrote), or a calibration library folder "
                    "(glsim calib library): its pairs page by page with the detected points drawn over them")
    ap.add_argument("--screenshot", metavar="OUT.png", help="draw the preview once without any display (EGL) and "
                    "save it as PNG")
    ap.add_argument("--size", type=int, nargs=2, default=(1280, 800), metavar=("W", "H"), help="window/frame size in px")
    ap.add_argument("--step", type=int, help="load step to show first (a calibration library: the page)")
    ap.add_argument("--overlay", action="append", choices=OVERLAYS, default=[], help="switch an overlay on (repeatable)")
    ap.add_argument("--drag-width", type=int, help="camera width (px) rendered while dragging (default: as shown)")
    ap.add_argument("--save-to", help="where the panel's 'save scene TOML' writes (default SCENE_preview.toml)")
    ap.add_argument("--log-frames", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--no-timings", action="store_true", help="leave render times out of the frame (reproducible "
                    "screenshots)")
    return ap


def main(argv: list[str]) -> int:
    args = parser().parse_args(argv)
    if args.size[0] < 320 or args.size[1] < 240:
        raise GlsimError(f"--size {args.size[0]} {args.size[1]}: the preview needs at least 320 240")
    from glsim.workflows.preview import calibpager

    if calibpager.is_library(args.scene):
        return _library(args)
    scene = load_scene(args.scene)          # a bad scene: the same named error as `glsim render`
    kwargs = {"drag_width": args.drag_width, "save_path": args.save_to}
    if args.screenshot:
        from glsim.workflows.preview.core import Preview

        with Preview(scene, size=tuple(args.size), **kwargs) as pv:
            pv.show_timings = not args.no_timings
            _initial(pv, args)
            out = pv.screenshot(args.screenshot)
        print(f"glsim preview: wrote {out} ({args.size[0]}x{args.size[1]})")
        return 0
    from glsim.workflows.preview import window

    if not window.has_display():
        raise GlsimError(window.NO_DISPLAY)
    return window.run(scene, size=tuple(args.size), log_frames=args.log_frames, show_timings=not args.no_timings,
                      initial=lambda pv: _initial(pv, args), **kwargs)


def _initial(pv, args) -> None:
    if args.step is not None:
        if not 0 <= args.step < pv.model.n_steps:
            raise GlsimError(f"--step {args.step}: the scene has load steps 0…{pv.model.n_steps - 1}")
        pv.set("step", args.step)
    for name in args.overlay:
        pv.set(f"overlay:{name}", True)


def _library(args) -> int:
    """A calibration library: page through its pairs (window) or draw the first page (--screenshot)."""
    from glsim.workflows.preview.calibpager import LibraryPager

    def make(ctx=None):
        pager = LibraryPager(args.scene, size=tuple(args.size))
        if args.step is not None:
            if not 0 <= args.step < len(pager.lib.pairs):
                raise GlsimError(f"--step {args.step}: the library has pages 0…{len(pager.lib.pairs) - 1}")
            pager.go(args.step)
        return pager

    if args.screenshot:
        with make() as pager:
            out = pager.screenshot(args.screenshot)
        print(f"glsim preview: wrote {out} ({args.size[0]}x{args.size[1]}, pair {pager.lib.pairs[pager.page]['pair']})")
        return 0
    from glsim.workflows.preview import window

    if not window.has_display():
        raise GlsimError(window.NO_DISPLAY)
    make().close()                     # a broken library is named before a window opens
    return window.run(None, size=tuple(args.size), log_frames=args.log_frames, make=make)
