"""GTSAM 4.3 peer for subnav's batch factor graph (host/src/fgo): the same IMU + bias random
walk + DVL + USBL + prior problem, solved with GTSAM's Levenberg-Marquardt.

- IMU: gtsam.ImuFactor on PreintegratedImuMeasurements integrated from the same samples, with
  ImuFactorErrorMode.ComponentWise (the residual subnav implements).
- Bias random walk: BetweenFactorConstantBias.
- DVL: a CustomFactor (python), residual v_meas - R_bd^T (R^T v + w x l).
- USBL: a CustomFactor, residual p_meas - (t + R l).
- Prior on node 0: PoseRotationPrior3D, PoseTranslationPrior3D, PriorFactorVector (velocity),
  PriorFactorConstantBias.

stdin: the problem JSON written by tests/tests/peer_gtsam.rs; stdout: optimised states + timing.
"""
import json
import sys
import time

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, V, X


def skew(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def dvl_factor(key_x, key_v, meas, r_bd, lever, omega, cov):
    def err(this, values, H):
        pose = values.atPose3(key_x)
        vel = values.atVector(key_v)
        r = pose.rotation().matrix()
        v_body = r.T @ vel
        pred = r_bd.T @ (v_body + np.cross(omega, lever))
        if H is not None:
            # Pose3 tangent [w, t]: rotation perturbed on the right, translation irrelevant
            H[0] = np.hstack([-r_bd.T @ skew(v_body), np.zeros((3, 3))])
            H[1] = -r_bd.T @ r.T
        return meas - pred

    return gtsam.CustomFactor(gtsam.noiseModel.Gaussian.Covariance(cov), [key_x, key_v], err)


def usbl_factor(key_x, meas, lever, cov):
    def err(this, values, H):
        pose = values.atPose3(key_x)
        r = pose.rotation().matrix()
        pred = pose.translation() + r @ lever
        if H is not None:
            # d(t)/d(t_body) = R for Pose3's retract; d(R l)/dw = -R [l]x
            H[0] = np.hstack([r @ skew(lever), -r])
        return meas - pred

    return gtsam.CustomFactor(gtsam.noiseModel.Gaussian.Covariance(cov), [key_x], err)


def arr(x):
    return np.array(x, dtype=float)


def main():
    d = json.load(sys.stdin)
    prm = d["params"]
    p = gtsam.PreintegrationParams(arr(prm["gravity"]))
    p.setAccelerometerCovariance(arr(prm["acc_cov"]))
    p.setGyroscopeCovariance(arr(prm["gyro_cov"]))
    p.setIntegrationCovariance(arr(prm["int_cov"]))
    p.setImuFactorErrorMode(gtsam.ImuFactorErrorMode.ComponentWise)

    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    for k, n in enumerate(d["nodes"]):
        values.insert(X(k), gtsam.Pose3(gtsam.Rot3(arr(n["R"])), arr(n["p"])))
        values.insert(V(k), arr(n["v"]))
        values.insert(B(k), gtsam.imuBias.ConstantBias(arr(n["ba"]), arr(n["bg"])))

    pr = d["prior"]
    s = pr["sigmas"]
    k0 = pr["node"]
    graph.add(gtsam.PoseRotationPrior3D(X(k0), gtsam.Rot3(arr(pr["R"])), gtsam.noiseModel.Isotropic.Sigma(3, s[0])))
    graph.add(gtsam.PoseTranslationPrior3D(X(k0), arr(pr["p"]), gtsam.noiseModel.Isotropic.Sigma(3, s[1])))
    graph.add(gtsam.PriorFactorVector(V(k0), arr(pr["v"]), gtsam.noiseModel.Isotropic.Sigma(3, s[2])))
    graph.add(gtsam.PriorFactorConstantBias(
        B(k0), gtsam.imuBias.ConstantBias(arr(pr["ba"]), arr(pr["bg"])),
        gtsam.noiseModel.Diagonal.Sigmas(np.array([s[3]] * 3 + [s[4]] * 3))))

    max_cov_mismatch = 0.0
    for f in d["imu"]:
        bh = arr(f["bias_hat"])
        pim = gtsam.PreintegratedImuMeasurements(p, gtsam.imuBias.ConstantBias(bh[:3], bh[3:]))
        for smp in f["samples"]:
            pim.integrateMeasurement(arr(smp[0:3]), arr(smp[3:6]), float(smp[6]))
        i, j = f["i"], f["j"]
        fac = gtsam.ImuFactor(X(i), V(i), X(j), V(j), B(i), pim)
        cov = fac.noiseModel().covariance()
        max_cov_mismatch = max(max_cov_mismatch, float(np.abs(cov - pim.preintMeasCov()).max() / np.abs(cov).max()))
        graph.add(fac)
    for f in d["bias_rw"]:
        graph.add(gtsam.BetweenFactorConstantBias(
            B(f["i"]), B(f["j"]), gtsam.imuBias.ConstantBias(),
            gtsam.noiseModel.Gaussian.Covariance(arr(f["cov"]))))
    for f in d["dvl"]:
        graph.add(dvl_factor(X(f["node"]), V(f["node"]), arr(f["vel"]), arr(f["R_bd"]), arr(f["lever"]),
                             arr(f["omega"]), arr(f["cov"])))
    for f in d["usbl"]:
        graph.add(usbl_factor(X(f["node"]), arr(f["pos"]), arr(f["lever"]), arr(f["cov"])))

    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(100)
    params.setRelativeErrorTol(1e-10)
    params.setAbsoluteErrorTol(1e-10)
    initial_error = graph.error(values)
    t0 = time.perf_counter()
    opt = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    res = opt.optimize()
    solve_s = time.perf_counter() - t0

    nodes = []
    for k in range(len(d["nodes"])):
        pose = res.atPose3(X(k))
        b = res.atConstantBias(B(k))
        nodes.append({
            "R": pose.rotation().matrix().tolist(),
            "p": np.asarray(pose.translation()).tolist(),
            "v": np.asarray(res.atVector(V(k))).tolist(),
            "ba": np.asarray(b.accelerometer()).tolist(),
            "bg": np.asarray(b.gyroscope()).tolist(),
        })
    json.dump({
        "nodes": nodes,
        "solve_s": solve_s,
        "iterations": opt.iterations(),
        "initial_error": initial_error,
        "final_error": graph.error(res),
        "imu_noise_vs_preint_cov_max_rel": max_cov_mismatch,
    }, sys.stdout)


if __name__ == "__main__":
    main()
