"""Peer run for tests/tests/peer_filterpy.rs: FilterPy 2.0.0 UnscentedKalmanFilter with
MerweScaledSigmaPoints on a coordinated-turn target tracked by range/bearing to a beacon.

State [px, py, v, psi, omega] (psi wrapped), measurements [range, bearing] every step and an
extra range-only update on some steps (sigma points re-drawn first, as
`compute_process_sigmas`' docstring describes). Reads the problem as JSON (argv[1]), writes
x and P after every step as JSON (argv[2]).
"""
import json
import math
import sys

import numpy as np
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter


def wrap(a):
    a = math.fmod(a, 2.0 * math.pi)
    if a > math.pi:
        a -= 2.0 * math.pi
    elif a <= -math.pi:
        a += 2.0 * math.pi
    return a


def main():
    prob = json.load(open(sys.argv[1]))
    bx, by = prob["beacon"]

    def fx(x, dt):
        px, py, v, psi, om = x
        return np.array([px + v * math.cos(psi) * dt, py + v * math.sin(psi) * dt, v,
                         wrap(psi + om * dt), om])

    def hx2(x):
        dx, dy = x[0] - bx, x[1] - by
        return np.array([math.hypot(dx, dy), math.atan2(dy, dx)])

    def hx1(x):
        return np.array([math.hypot(x[0] - bx, x[1] - by)])

    def residual_x(a, b):
        y = np.asarray(a, dtype=float) - np.asarray(b, dtype=float)
        y[3] = wrap(y[3])
        return y

    def state_add(x, dx):
        y = np.asarray(x, dtype=float) + np.asarray(dx, dtype=float)
        y[3] = wrap(y[3])
        return y

    def x_mean(sigmas, wm):
        x = np.dot(wm, sigmas)
        x[3] = math.atan2(np.dot(wm, np.sin(sigmas[:, 3])), np.dot(wm, np.cos(sigmas[:, 3])))
        return x

    def residual_z2(a, b):
        y = np.asarray(a, dtype=float) - np.asarray(b, dtype=float)
        y[1] = wrap(y[1])
        return y

    def z_mean2(sigmas, wm):
        z = np.dot(wm, sigmas)
        z[1] = math.atan2(np.dot(wm, np.sin(sigmas[:, 1])), np.dot(wm, np.cos(sigmas[:, 1])))
        return z

    out = []
    for cfg in prob["configs"]:
        pts = MerweScaledSigmaPoints(5, alpha=cfg["alpha"], beta=cfg["beta"], kappa=cfg["kappa"],
                                     subtract=residual_x)
        ukf = UnscentedKalmanFilter(dim_x=5, dim_z=2, dt=prob["dt"], fx=fx, hx=hx2, points=pts,
                                    x_mean_fn=x_mean, z_mean_fn=z_mean2,
                                    residual_x=residual_x, residual_z=residual_z2,
                                    state_add=state_add)
        ukf.x = np.array(prob["x0"], dtype=float)
        ukf.P = np.array(prob["p0"], dtype=float)
        ukf.Q = np.array(prob["q"], dtype=float)
        R2 = np.array(prob["r2"], dtype=float)
        R1 = np.array(prob["r1"], dtype=float)
        xs, ps = [], []
        for step in prob["steps"]:
            ukf.predict()
            ukf.update(np.array(step["z2"]), R=R2)
            if step["z1"] is not None:
                ukf.sigmas_f = ukf.points_fn.sigma_points(ukf.x, ukf.P)
                ukf.residual_z, ukf.z_mean = np.subtract, None
                ukf.update(np.array([step["z1"]]), R=R1, hx=hx1)
                ukf.residual_z, ukf.z_mean = residual_z2, z_mean2
            xs.append(ukf.x.tolist())
            ps.append(ukf.P.tolist())
        out.append({"x": xs, "p": ps})
    json.dump(out, open(sys.argv[2], "w"))


if __name__ == "__main__":
    main()
