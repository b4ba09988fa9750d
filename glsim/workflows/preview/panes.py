"""The preview frame's panes, drawn with numpy/OpenCV: the camera tiles with their overlays, the
info area (figures, messages, colour bar) and the control panel. :class:`Panes` is a part of
:class:`~glsim.workflows.preview.core.Preview` and draws from its state."""
from __future__ import annotations

import cv2
import numpy as np

from glsim.workflows.preview import draw, overlays as ov

ROW = 19            # panel row height, px


def display_grey(image: np.ndarray, bit_depth: int) -> np.ndarray:
    """What the camera records (quantised to its bit depth, clipped) as 8-bit display grey."""
    top = (1 << bit_depth) - 1
    q = np.clip(np.rint(np.asarray(image, np.float64) * top), 0, top)
    return (q if bit_depth == 8 else np.rint(q * (255.0 / top))).astype(np.uint8)


class Panes:
    """The drawing of :class:`~glsim.workflows.preview.core.Preview`'s frame, pane by pane."""

    def _draw_tile(self, frame, i: int, box, res, data: dict) -> None:
        x, y, w, h = box
        cam = self.scene.cameras[i]
        grey = display_grey(res.image, cam.bit_depth)
        if grey.shape != (h, w):
            interp = cv2.INTER_AREA if grey.shape[1] > w else cv2.INTER_LINEAR
            grey = cv2.resize(grey, (w, h), interpolation=interp)
        tile = np.repeat(grey[..., None], 3, axis=2).astype(np.float32)

        def fit(a, interp=cv2.INTER_NEAREST):
            a = np.asarray(a)
            if a.shape[:2] == (h, w):
                return a
            return cv2.resize(a.astype(np.float32) if a.dtype == bool else a, (w, h), interpolation=interp)

        def blend(mask, colour, alpha):
            m = fit(mask.astype(np.uint8)).astype(bool)
            tile[m] = (1 - alpha) * tile[m] + alpha * np.asarray(colour, np.float32)

        if "displacement" in data:
            d = data["displacement"]
            lo, hi = self._disp_range(d)
            rgb = fit(ov.colour_map(d, lo, hi))
            m = fit(np.isfinite(d).astype(np.uint8)).astype(bool)
            tile[m] = 0.35 * tile[m] + 0.65 * rgb[m]
        if "coc" in data:
            c = data["coc"]
            limit = self.scene.optics.coc_px
            rgb = fit(ov.colour_map(c, 0.0, self._coc_hi(c)))
            m = fit(np.isfinite(c).astype(np.uint8)).astype(bool)
            tile[m] = 0.35 * tile[m] + 0.65 * rgb[m]
            with np.errstate(invalid="ignore"):
                blurred = fit((c > limit).astype(np.uint8))
            edge = cv2.morphologyEx(blurred, cv2.MORPH_GRADIENT, np.ones((3, 3), np.uint8)).astype(bool) & m
            tile[edge] = (255, 255, 255)
        if "overlap" in data:
            blend(data["overlap"], (60, 220, 90), 0.35)
            blend(data["covered"] & ~data["overlap"], (230, 60, 200), 0.55)
        if "above" in data:
            for mask, colour in ((data["above"], (255, 30, 30)), (data["below"], (40, 80, 255))):
                if mask.any():
                    m = mask if mask.shape == (h, w) else cv2.resize(mask.astype(np.uint8), (w, h),
                                                                     interpolation=cv2.INTER_AREA) > 0
                    if mask.shape != (h, w):   # keep isolated clipped pixels visible when shrunk
                        m |= cv2.resize(cv2.dilate(mask.astype(np.uint8), np.ones((3, 3), np.uint8)), (w, h),
                                        interpolation=cv2.INTER_NEAREST) > 0
                    tile[m] = colour
        out = np.clip(tile, 0, 255).astype(np.uint8)
        if self.p.overlays["edges"]:
            s = w / cam.width
            lines = ov.edge_polylines(cam, self.mesh.deformed(self.p.step), self.mesh.quads)
            pts = [np.rint(((ln + 0.5) * s - 0.5) * 16).astype(np.int32) for ln in lines]
            if pts:
                cv2.polylines(out, pts, False, (255, 220, 40), 1, cv2.LINE_AA, shift=4)
        sp = data.get("speckle")
        if sp is not None:
            s = w / cam.width
            r0, r1, c0, c1 = sp["region"]
            cv2.rectangle(out, (int(c0 * s), int(r0 * s)), (int(c1 * s), int(r1 * s)), (80, 230, 255), 1)
        frame[y:y + h, x:x + w] = out
        colour = draw.CAMERA_COLOURS[i % len(draw.CAMERA_COLOURS)]
        if i == self.p.camera:
            cv2.rectangle(frame, (x - 2, y - 2), (x + w + 1, y + h + 1), colour, 2)
        label = f"{cam.name}  {cam.width}x{cam.height}  {res.options.mode}"
        if self.show_timings:
            label += f"  {res.seconds * 1e3:.0f} ms"
        if res.camera.size != cam.size:
            label += f"  (preview {res.camera.width}x{res.camera.height})"
        draw.text(frame, label, x + 2, y - 5, colour, 0.4)

    @staticmethod
    def _disp_range(d):
        if not np.isfinite(d).any():
            return 0.0, 1.0
        lo, hi = float(np.nanmin(d)), float(np.nanmax(d))
        if lo >= 0 or hi <= 0:
            lo = min(lo, 0.0)
        return (lo, hi) if hi > lo else (lo, lo + 1e-3)

    @staticmethod
    def _coc_hi(c):
        m = float(np.nanmax(c)) if np.isfinite(c).any() else 1.0
        return max(m, 1e-3)

    def _info(self, frame, box, data_all, res) -> None:
        x, y, w, h = box
        frame[y:y + h, x:x + w] = (20, 20, 24)
        p, cams = self.p, self.scene.cameras
        ly = y + 16

        def line(s, colour=draw.WHITE, scale=0.42):
            nonlocal ly
            if ly < y + h - 4:
                draw.text(frame, s, x + 8, ly, colour, scale)
            ly += 17

        q = self._frame_quality or self.quality
        t = self.timings.get(f"render_{q}", 0.0)
        line(f"step {p.step}/{self.model.n_steps - 1}   mode {self.scene.render.mode}   "
             f"{'playing' if p.playing else ''}  {'preview (fast)' if q == 'fast' else 'full quality'}" +
             (f" {t * 1e3:.0f} ms" if self.show_timings else ""))
        sc = self.scene
        fx = [n for n, on in (("lighting", sc.lighting), ("DOF", sc.optics), ("noise", sc.noise), ("PSF", sc.psf),
                              ("vignetting", sc.vignetting), ("FPN", sc.sensor), ("motion", sc.exposure)) if on]
        line("effects: " + (", ".join(fx) or "none"), draw.GREY)
        if self.show_help:
            for k in ("keys: <- -> step, space play, c camera, m mode, 1-7 effects",
                      "d disp. (v component), e edges, o overlap, f CoC, k clipped",
                      "z speckle, g range, [ ] stereo angle, - = distance, , . focal",
                      "n N f-number, w save TOML, p screenshot, r reset view, q quit"):
                line(k, draw.GREY, 0.38)
        for i, (cam, data) in enumerate(zip(cams, data_all)):
            colour = draw.CAMERA_COLOURS[i % len(draw.CAMERA_COLOURS)]
            parts = []
            if "speckle" in data:
                sp = data["speckle"]
                parts.append("speckle: too little specimen" if sp is None else
                             f"speckle {sp['dot_diameter_px']:.2f} px (dots), {sp['speckle_diameter_px']:.2f} px (blobs)")
            elif p.overlays["speckle"]:
                parts.append("speckle: measured after refinement")
            if "range_px" in data:
                lo, hi = data["range_px"]
                parts.append(f"displacement {lo:.2f}-{hi:.2f} px")
            if "above" in data:
                n = max(data["specimen_px"], 1)
                parts.append(f"clipped {100 * data['above'].sum() / n:.2g}% high, {100 * data['below'].sum() / n:.2g}% "
                              "low (of the specimen's pixels)")
            if "coc" in data:
                c = data["coc"]
                near, far = data["dof"]
                cmax = float(np.nanmax(c)) if np.isfinite(c).any() else float("nan")
                dep = data.get("depth")
                parts.append(f"CoC max {cmax:.2f} px; DOF {near:.1f}-{far:.1f} mm" +
                             (f"; surface {dep[0]:.1f}-{dep[1]:.1f} mm" if dep else ""))
            elif p.overlays["coc"]:
                parts.append("CoC: depth of field is off (switch it on)")
            if "overlap" in data:
                cov = data["covered"].sum()
                parts.append(f"seen by both {100 * data['overlap'].sum() / max(cov, 1):.3g}% of specimen px")
            if parts:
                line(f"{cam.name}:", colour)
                for s in parts:
                    line("  " + s, draw.WHITE, 0.4)
        for m in self.messages[-3:]:
            line(m[:110], (255, 180, 120), 0.38)
        # colour bar of the active camera's map
        data = data_all[p.camera]
        bw, bx, by = w - 90, x + 12, y + h - 52
        if "displacement" in data and by > ly:
            lo, hi = self._disp_range(data["displacement"])
            mmpx = data["mm_per_px"]
            draw.colour_bar(frame, bx, by, bw, 12, lo, hi, ov.nice_ticks(lo, hi),
                            f"{cams[p.camera].name}: displacement {p.component} (mm; px at {mmpx:.3g} mm/px)",
                            (1 / mmpx, "px"))
        elif "coc" in data and by > ly:
            hi = self._coc_hi(data["coc"])
            draw.colour_bar(frame, bx, by, bw, 12, 0.0, hi, ov.nice_ticks(0.0, hi),
                            f"{cams[p.camera].name}: circle of confusion (px); white line: CoC = {self.scene.optics.coc_px:g} px")

    def _panel(self, frame, box) -> None:
        x, y, w, h = box
        frame[y:y + h, x:x + w] = (36, 36, 42)
        draw.text(frame, "controls (drag a value, click -/+)", x + 8, y + 14, draw.GREY, 0.38)
        ry = y + 22
        rows = list(self.controls.values())
        fit = max(1, (h - 22) // ROW)
        self._panel_offset = min(max(self._panel_offset, 0), max(0, len(rows) - fit))
        if len(rows) > fit:
            draw.text(frame, f"wheel: more ({self._panel_offset + 1}-{min(len(rows), self._panel_offset + fit)} "
                      f"of {len(rows)})", x + w - 120, y + h - 4, draw.GREY, 0.34)
            fit -= 1
        self._hits.append(((x, y, w, h), ("panel", None)))
        for c in rows[self._panel_offset:self._panel_offset + fit]:
            self._hits.append(((x, ry, w, ROW), ("control", c.name)))
            if c.kind == "toggle":
                on = self.get(c.name)
                cv2.rectangle(frame, (x + 8, ry + 4), (x + 19, ry + 15), draw.WHITE, 1)
                if on:
                    cv2.rectangle(frame, (x + 10, ry + 6), (x + 17, ry + 13), (120, 220, 120), -1)
                draw.text(frame, ("overlay: " if c.name.startswith("overlay:") else "") + c.label, x + 26, ry + 14,
                          draw.WHITE, 0.4)
            elif c.kind == "button":
                cv2.rectangle(frame, (x + 8, ry + 2), (x + w - 8, ry + ROW - 2), (70, 70, 80), -1)
                label = ("stop" if self.p.playing else "play") + " load steps" if c.name == "play" else c.label
                draw.text(frame, label, x + 14, ry + 14, draw.WHITE, 0.4)
            else:
                v = self.get(c.name)
                if c.kind == "choice":
                    vs = c.options[v] if c.name == "camera" else str(v)
                elif c.kind == "int":
                    vs = str(v)
                else:
                    vs = f"{v:.4g}{c.unit and ' ' + c.unit}"
                draw.text(frame, c.label, x + 8, ry + 13, draw.WHITE, 0.4)
                draw.text(frame, vs, x + w - 44 - draw.text_width(vs, 0.4), ry + 13, (255, 230, 150), 0.4)
                if c.kind in ("slider", "int"):
                    frac = (float(v) - c.lo) / (c.hi - c.lo) if c.hi > c.lo else 0.0
                    x0, x1 = x + 8, x + w - 44
                    cv2.line(frame, (x0, ry + 17), (x1, ry + 17), (80, 80, 90), 2)
                    cv2.line(frame, (x0, ry + 17), (x0 + int(np.clip(frac, 0, 1) * (x1 - x0)), ry + 17), (120, 170, 255), 2)
                draw.text(frame, "-", x + w - 34, ry + 14, draw.WHITE, 0.5)
                draw.text(frame, "+", x + w - 18, ry + 14, draw.WHITE, 0.5)
            ry += ROW
