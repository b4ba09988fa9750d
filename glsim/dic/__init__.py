"""``glsim verify``: glsim's images measured by an independent DIC (pyvale in ``.venv-verify``) —
the stereo bulge against its imposed coordinates (:mod:`~glsim.dic.verify`) and the rigid-body
sweep's S-curves and the accuracy–time frontier (:mod:`~glsim.dic.sweep`,
:mod:`~glsim.dic.sweep_report`, :mod:`~glsim.dic.frontier`)."""
