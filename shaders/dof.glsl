// Depth of field (reference paper eqs. 17-19): the GLSL twin of glsim/effects/dof.py (coc_px,
// blur_sigma, blur_radius; same formulas, same in-focus rule). Lengths in mm, blur in pixels.
// CoC = f^2 |P - D| / (N (P - f) D) is eq. 19 rewritten without the cancellation of V_D - V_P.
// In FP64 builds (the blur passes where the driver has fp64) it is evaluated in double from
// double uniforms, in numpy's order of operations: a pixel's sigma and window then equal the
// oracle's bit for bit for the same (float32) depth, so both decide the in-focus threshold
// and the window ceil(3 sigma) alike. In float (P - D of two float32 depths is exact by
// Sterbenz's lemma when they are within a factor 2) the relative error is a few ulps.
uniform real u_focal_length;    // f, mm
uniform real u_f_number;        // N
uniform real u_focus_distance;  // D, mm along the optical axis
uniform real u_pixel_pitch;     // mm per pixel
uniform real u_coc_px;          // acceptable circle of confusion, pixels (in focus: CoC <= it)

// Circle of confusion in pixels of a point at camera-frame depth Z (mm); valid for Z > f.
real coc_px(real Z) {
    real f = u_focal_length;
    real D = u_focus_distance;
    return f * f * abs(Z - D) / (u_f_number * (Z - f) * D) / u_pixel_pitch;
}

// Half the blur-spot diameter (px) outside the depth of field; 0 inside it (CoC <= u_coc_px)
// and where there is no surface (Z <= 0). numpy raises for 0 < Z <= f; here such depths
// (no real image) count as no surface.
real blur_size(real Z) {
    if (Z <= u_focal_length) return real(0.0);
    real c = coc_px(Z);
    return c > u_coc_px ? real(0.5) * c : real(0.0);
}

// Gaussian sigma (px): half the blur-spot diameter.
real blur_sigma(real Z) { return blur_size(Z); }

// Disk-kernel radius (px): half the blur-spot diameter.
real blur_radius(real Z) { return blur_size(Z); }
