"""How one :class:`glsim.render.Result` is put together from the backend's renders, between the
backends and the entry point (:mod:`glsim.render`, which composes these):

- :mod:`.drawing`: what composing needs of a renderer (its scene, meshes, reference, backend);
- :mod:`.truth`: truth assembly from a raster (:class:`~.truth.TruthAssembler`; the per-pixel
  maps by default, the library's compact triples in :mod:`glsim.workflows.library.worker`);
- :mod:`.chain`: the image Jacobian from a float64 raster, chained through the quadratic
  mesh's pieces, the depth of field, the exposure's state and the camera effects;
- :mod:`.exposure`: an exposure's sub-frames and a rolling shutter's rows, averaged, with their
  truth and Jacobian.
"""
