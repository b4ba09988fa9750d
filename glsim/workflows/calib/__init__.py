"""Calibration targets, image libraries, detection, stereo calibration and Monte-Carlo studies
(see docs/calib.md).

``targets`` (DotGrid, Chessboard, Charuco as glsim specimens) → ``poses`` (roll, twist,
plunge, translation, mixes over the field of view) → ``library`` (rendered stereo pairs, ground
truth, the Table 8 rig) → ``detect`` (dot grids) → ``calibrate`` (OpenCV stereo calibration,
report, epipolar map) → ``study`` (bootstrap calibrations, figures); ``cli`` is ``glsim calib``.
"""
