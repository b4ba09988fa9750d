// Camera model: the GLSL twin of glsim/scene/camera.py (same function names, argument order, conventions).
// Needs the loader's precision macros (real, real2, real3, real2x2; double precision when FP64).
//   k[12]    = (k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4), OpenCV order, no tilt
//   intr[5]  = (fx, fy, skew, cx, cy) px; pixel centres at integer coordinates
//   valid_r2 = glsim.scene.camera.valid_radius(k)^2, the squared normalized radius where the
//              radial mapping stops increasing (may be +inf)

// Residual tolerance of undistort, relative to 1 + |xd|. In single precision distort's own
// rounding leaves residuals up to ~5e-8, so 2e-7 keeps a margin (~1e-3 px at f = 2000 px).
#ifdef FP64
#define UNDISTORT_TOL 1e-14lf
#else
#define UNDISTORT_TOL 2e-7
#endif
#define UNDISTORT_MAX_ITER 20
#define UNDISTORT_MAX_HALVINGS 20

#ifdef APERTURE
// The pixel point of sample `q` (its index on the SS-times grid) on a sensor of fill factor
// f < 1: its offset from the pixel centre scaled by APERTURE = sqrt(f) (a real, exact), in
// glsim.scene.camera.pixel_grid's operations and order.
real2 aperture_sample(ivec2 q) {
    ivec2 pix = q / SS;
    precise real2 off = (real2(q - pix * SS) + real(0.5)) / real(SS) - real(0.5);
    precise real2 px = real2(pix) + APERTURE * off;
    return px;
}
#endif

// (radial factor, its derivative with respect to r2)
// `precise` here and below: numpy's operations in numpy's order, so that FP64 builds give the
// oracle's projections bit for bit on every driver (no contraction into fused multiply-adds).
real2 distortion_radial(real r2, real k[12]) {
    precise real num = 1.0 + r2 * (k[0] + r2 * (k[1] + r2 * k[4]));
    precise real den = 1.0 + r2 * (k[5] + r2 * (k[6] + r2 * k[7]));
    precise real dnum = k[0] + r2 * (2.0 * k[1] + 3.0 * r2 * k[4]);
    precise real dden = k[5] + r2 * (2.0 * k[6] + 3.0 * r2 * k[7]);
    precise real radial = num / den;
    precise real dradial = (dnum - radial * dden) / den;
    return real2(radial, dradial);
}

// Normalized undistorted xn -> normalized distorted xd (OpenCV's model).
real2 distort(real2 xn, real k[12]) {
    real x = xn.x, y = xn.y;
    precise real r2 = x * x + y * y;
    real radial = distortion_radial(r2, k).x;
    precise real xd = x * radial + 2.0 * k[2] * x * y + k[3] * (r2 + 2.0 * x * x) + r2 * (k[8] + k[9] * r2);
    precise real yd = y * radial + k[2] * (r2 + 2.0 * y * y) + 2.0 * k[3] * x * y + r2 * (k[10] + k[11] * r2);
    return real2(xd, yd);
}

// d xd / d xn. GLSL matrices are column-major: J[col][row], so J[j][i] = d xd_i / d xn_j.
real2x2 distort_jacobian(real2 xn, real k[12]) {
    real x = xn.x, y = xn.y;
    real r2 = x * x + y * y;
    real2 rad = distortion_radial(r2, k);
    real cross = 2.0 * x * y * rad.y;
    real sx = 2.0 * (k[8] + 2.0 * k[9] * r2);
    real sy = 2.0 * (k[10] + 2.0 * k[11] * r2);
    real j00 = rad.x + 2.0 * x * x * rad.y + 2.0 * k[2] * y + 6.0 * k[3] * x + x * sx;
    real j01 = cross + 2.0 * k[2] * x + 2.0 * k[3] * y + y * sx;
    real j10 = cross + 2.0 * k[2] * x + 2.0 * k[3] * y + x * sy;
    real j11 = rad.x + 2.0 * y * y * rad.y + 6.0 * k[2] * y + 2.0 * k[3] * x + y * sy;
    return real2x2(j00, j10, j01, j11);
}

// Invert distort: damped Newton from xn = xd, halving the step while the residual does not fall;
// converged when |distort(xn) - xd| <= UNDISTORT_TOL * (1 + |xd|). Returns false (and xn = 0)
// where it did not converge or xn lies at or beyond the valid radius.
bool undistort(real2 xd, real k[12], real valid_r2, out real2 xn) {
    real thresh = UNDISTORT_TOL * (1.0 + length(xd));
    xn = xd;
    real2 f = distort(xn, k) - xd;
    real res = length(f);
    for (int i = 0; i < UNDISTORT_MAX_ITER && res > thresh; ++i) {
        real2x2 J = distort_jacobian(xn, k);
        if (!(abs(determinant(J)) > 0.0)) break;
        real2 step = -(inverse(J) * f);
        real lam = 1.0;
        bool accepted = false;
        for (int h = 0; h < UNDISTORT_MAX_HALVINGS && !accepted; ++h) {
            real2 trial = xn + lam * step;
            real2 ft = distort(trial, k) - xd;
            real rt = length(ft);
            if (rt < res) {
                xn = trial;
                f = ft;
                res = rt;
                accepted = true;
            }
            lam *= 0.5;
        }
        if (!accepted) break;  // stuck
    }
    bool ok = res <= thresh && dot(xn, xn) < valid_r2;
    if (!ok) xn = real2(0.0);
    return ok;
}

// Pixels -> normalized distorted coordinates (inverse of K).
real2 pixel_to_normalized(real2 uv, real intr[5]) {
    precise real yd = (uv.y - intr[4]) / intr[1];
    precise real xd = (uv.x - intr[3] - intr[2] * yd) / intr[0];
    return real2(xd, yd);
}

// Normalized distorted coordinates -> pixels: u = fx xd + skew yd + cx, v = fy yd + cy.
real2 normalized_to_pixel(real2 xd, real intr[5]) {
    precise real u = intr[0] * xd.x + intr[2] * xd.y + intr[3];
    precise real v = intr[1] * xd.y + intr[4];
    return real2(u, v);
}

// Camera-frame point (mm) -> pixels. False for Z <= 0 or beyond the valid radius; uv is then
// the principal point.
bool project_camera_frame(real3 Xc, real intr[5], real k[12], real valid_r2, out real2 uv) {
    bool ok = Xc.z > 0.0;
    real2 xn = ok ? Xc.xy / Xc.z : real2(0.0);
    ok = ok && dot(xn, xn) < valid_r2;
    if (!ok) xn = real2(0.0);
    uv = normalized_to_pixel(distort(xn, k), intr);
    return ok;
}
