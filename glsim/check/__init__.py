"""``glsim check``: does the GL path give the CPU oracle's answer on this machine's driver?
:mod:`~glsim.check.runner` runs the checks; each is measured in units of a bound derived from
the arithmetic — :mod:`~glsim.check.closed_forms` (float32/float64 rounding, ties, the passes'
float32 error, from numbers and arrays), :mod:`~glsim.check.oracle_maps` (the same per pixel of a
scene, from the oracle's own maps), :mod:`~glsim.check.exact32` (the float32 exact build) and
:mod:`~glsim.check.shapefilter` (the GPU's shape filter). The GL tests assert the same bounds."""
