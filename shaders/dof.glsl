// Depth of field (reference paper eqs. 17-19): the GLSL twin of glsim/effects/dof.py (coc_px,
// blur_sigma, blur_radius; same formulas, same in-focus rule). Lengths in mm, blur in pixels.
// Evaluated in float: CoC = f^2 |P - D| / (N (P - f) D) is eq. 19 rewritten without the
// cancellation of V_D - V_P (P - D of two float32 depths is exact by Sterbenz's lemma when
// they are within a factor 2, so the relative error stays a few ulps even next to the focus).
uniform float u_focal_length;    // f, mm
uniform float u_f_number;        // N
uniform float u_focus_distance;  // D, mm along the optical axis
uniform float u_pixel_pitch;     // mm per pixel
uniform float u_coc_px;          // acceptable circle of confusion, pixels (in focus: CoC <= it)

// Circle of confusion in pixels of a point at camera-frame depth Z (mm); valid for Z > f.
float coc_px(float Z) {
    float f = u_focal_length;
    float D = u_focus_distance;
    return f * f * abs(Z - D) / (u_f_number * (Z - f) * D) / u_pixel_pitch;
}

// Half the blur-spot diameter (px) outside the depth of field; 0 inside it (CoC <= u_coc_px)
// and where there is no surface (Z <= 0). numpy raises for 0 < Z <= f; here such depths
// (no real image) count as no surface.
float blur_size(float Z) {
    if (Z <= u_focal_length) return 0.0;
    float c = coc_px(Z);
    return c > u_coc_px ? 0.5 * c : 0.0;
}

// Gaussian sigma (px): half the blur-spot diameter.
float blur_sigma(float Z) { return blur_size(Z); }

// Disk-kernel radius (px): half the blur-spot diameter.
float blur_radius(float Z) { return blur_size(Z); }
