"""The same matched points give the same stereo calibration to the bit: OpenCV's solvers run on one
thread inside glsim's calibrate (with several, stereoCalibrate's sums come out in another order
from run to run), and the caller's thread count is restored afterwards."""
import cv2
import numpy as np

from glsim.workflows.calib.calibrate import calibrate


def _views(n=8, seed=0):
    """A 9 × 9 grid (10 mm pitch) in n random poses, projected by two known pinholes with noise."""
    rng = np.random.default_rng(seed)
    g = np.stack(np.meshgrid(np.arange(9.0), np.arange(9.0)), -1).reshape(-1, 2) * 10 - 40
    obj = np.column_stack([g, np.zeros(len(g))])
    K = np.array([[2000.0, 0, 320], [0, 2000.0, 240], [0, 0, 1]])
    R12, _ = cv2.Rodrigues(np.array([0.0, np.radians(-20), 0.0]))
    T12 = np.array([200.0, 0.0, 30.0])
    objs, p1, p2 = [], [], []
    for _ in range(n):
        R, _ = cv2.Rodrigues(rng.normal(0, 0.25, 3))
        t = np.array([rng.normal(0, 10), rng.normal(0, 10), 600 + rng.normal(0, 30)])
        X1 = obj @ R.T + t
        X2 = X1 @ R12.T + T12
        objs.append(obj)
        p1.append(X1[:, :2] / X1[:, 2:] * 2000 + [320, 240] + rng.normal(0, 0.05, (len(g), 2)))
        p2.append(X2[:, :2] / X2[:, 2:] * 2000 + [320, 240] + rng.normal(0, 0.05, (len(g), 2)))
    return objs, p1, p2


def test_the_same_points_give_the_same_calibration_bits_and_the_thread_count_is_restored():
    objs, p1, p2 = _views()
    before = cv2.getNumThreads()
    cv2.setNumThreads(2)
    try:
        runs = [calibrate(objs, p1, p2, (640, 480)) for _ in range(3)]
        assert cv2.getNumThreads() == 2
    finally:
        cv2.setNumThreads(before)
    for r in runs[1:]:
        for name in ("K1", "D1", "K2", "D2", "R", "T"):
            assert getattr(r, name).tobytes() == getattr(runs[0], name).tobytes(), name
        assert r.rms == runs[0].rms
    # and the calibration is the one the points were made with (independent check of the inputs)
    assert abs(runs[0].K1[0, 0] - 2000.0) < 5 and np.linalg.norm(runs[0].T - [200.0, 0.0, 30.0]) < 2
