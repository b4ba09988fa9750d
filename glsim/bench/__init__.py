"""``glsim bench``: what accuracy costs on this machine — accuracy against the CPU oracle and time
per mode (:mod:`~glsim.bench.accuracy`), optical effects, throughput, scaling with elements and
image size, quadratic elements, riley-raster beside glsim (:mod:`~glsim.bench.peer`), the
Jacobian, libraries and the preview; each writes NAME.json and NAME.md (:mod:`~glsim.bench.report`,
numbers through :mod:`~glsim.bench.formatting`)."""
