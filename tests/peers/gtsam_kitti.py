"""GTSAM 4.3 peer for subnav's factor graph on the KITTI data GTSAM ships (subnav_fgo::kitti_run):
the same graph built from GTSAM's C++ factors only, solved three ways in one run.

Factors (no python CustomFactor):
- IMU: gtsam.ImuFactor on PreintegratedImuMeasurements (4.3 default: tangent preintegration)
  integrated from exactly the samples subnav integrated, ImuFactorErrorMode.ComponentWise;
- bias random walk: BetweenFactorConstantBias with subnav's covariance;
- fixes: gtsam.GPSFactor with subnav's covariance (after subnav's gate);
- prior on node 0: PoseRotationPrior3D, PoseTranslationPrior3D, PriorFactorVector,
  PriorFactorConstantBias (the pose, velocity and bias all constrained: the graph is determined).

Solvers: LevenbergMarquardtOptimizer from subnav's initial values (batch; then, untimed,
Gauss-Newton from its optimum for the 1e-6 agreement check); ISAM2 (default
parameters) fed epoch by epoch, a new node's initial value predicted from ISAM2's estimate of the
previous node; IncrementalFixedLagSmoother (ISAM2 inside) with subnav's lag, fed the same way.
Timed (best of `repeat` runs): only GTSAM's C++ calls (optimize; update + the newest node's estimate), wall
(perf_counter) and CPU (process_time); building the factors in python is not timed.
Run with OMP/MKL/TBB/OPENBLAS threads = 1 (the wheel links none of them; set anyway).

stdin: the problem JSON from subnav_fgo::kitti_run::gtsam_problem; stdout: results JSON.
"""
import json
import os
import sys
import time

for _v in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "TBB_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import gtsam  # noqa: E402
import numpy as np  # noqa: E402
from gtsam.symbol_shorthand import B, V, X  # noqa: E402


def arr(x):
    return np.array(x, dtype=float)


def node_out(pose, vel, bias):
    return {
        "R": pose.rotation().matrix().tolist(),
        "p": np.asarray(pose.translation()).tolist(),
        "v": np.asarray(vel).tolist(),
        "ba": np.asarray(bias.accelerometer()).tolist(),
        "bg": np.asarray(bias.gyroscope()).tolist(),
    }


def clock():
    return time.perf_counter(), time.process_time()


def main():
    d = json.load(sys.stdin)
    prm = d["params"]
    p = gtsam.PreintegrationParams(arr(prm["gravity"]))
    p.setAccelerometerCovariance(arr(prm["acc_cov"]))
    p.setGyroscopeCovariance(arr(prm["gyro_cov"]))
    p.setIntegrationCovariance(arr(prm["int_cov"]))
    p.setImuFactorErrorMode(gtsam.ImuFactorErrorMode.ComponentWise)
    n = len(d["nodes"])
    times = d["times"]

    # factors by the node they end at (all factors of a chain: node j's arrive with epoch j)
    at = [[] for _ in range(n)]
    pims = {}
    pr = d["prior"]
    s = pr["sigmas"]
    at[0].append(gtsam.PoseRotationPrior3D(X(0), gtsam.Rot3(arr(pr["R"])), gtsam.noiseModel.Isotropic.Sigma(3, s[0])))
    at[0].append(gtsam.PoseTranslationPrior3D(X(0), arr(pr["p"]), gtsam.noiseModel.Isotropic.Sigma(3, s[1])))
    at[0].append(gtsam.PriorFactorVector(V(0), arr(pr["v"]), gtsam.noiseModel.Isotropic.Sigma(3, s[2])))
    at[0].append(gtsam.PriorFactorConstantBias(
        B(0), gtsam.imuBias.ConstantBias(arr(pr["ba"]), arr(pr["bg"])),
        gtsam.noiseModel.Diagonal.Sigmas(np.array([s[3]] * 3 + [s[4]] * 3))))
    for f in d["imu"]:
        bh = arr(f["bias_hat"])
        pim = gtsam.PreintegratedImuMeasurements(p, gtsam.imuBias.ConstantBias(bh[:3], bh[3:]))
        for smp in f["samples"]:
            pim.integrateMeasurement(arr(smp[0:3]), arr(smp[3:6]), float(smp[6]))
        i, j = f["i"], f["j"]
        if j != i + 1:
            raise ValueError(f"IMU factor {i}->{j} is not between consecutive nodes")
        pims[j] = pim
        at[j].append(gtsam.ImuFactor(X(i), V(i), X(j), V(j), B(i), pim))
    for f in d["bias_rw"]:
        at[max(f["i"], f["j"])].append(gtsam.BetweenFactorConstantBias(
            B(f["i"]), B(f["j"]), gtsam.imuBias.ConstantBias(), gtsam.noiseModel.Gaussian.Covariance(arr(f["cov"]))))
    for f in d["gps"]:
        at[f["node"]].append(gtsam.GPSFactor(X(f["node"]), arr(f["pos"]), gtsam.noiseModel.Gaussian.Covariance(arr(f["cov"]))))

    # ---- batch LM
    graph = gtsam.NonlinearFactorGraph()
    for fs in at:
        for f in fs:
            graph.add(f)
    values = gtsam.Values()
    for k, nd in enumerate(d["nodes"]):
        values.insert(X(k), gtsam.Pose3(gtsam.Rot3(arr(nd["R"])), arr(nd["p"])))
        values.insert(V(k), arr(nd["v"]))
        values.insert(B(k), gtsam.imuBias.ConstantBias(arr(nd["ba"]), arr(nd["bg"])))
    lmp = gtsam.LevenbergMarquardtParams()
    lmp.setMaxIterations(int(d["lm"]["max_iterations"]))
    lmp.setRelativeErrorTol(float(d["lm"]["relative_tol"]))
    lmp.setAbsoluteErrorTol(float(d["lm"]["absolute_tol"]))
    initial_error = graph.error(values)
    rep = int(d.get("repeat", 1))
    lm_wall = lm_cpu = float("inf")
    for _ in range(rep):
        w0, c0 = clock()
        opt = gtsam.LevenbergMarquardtOptimizer(graph, values, lmp)
        res = opt.optimize()
        w1, c1 = clock()
        lm_wall, lm_cpu = min(lm_wall, w1 - w0), min(lm_cpu, c1 - c0)
    lm_nodes = [node_out(res.atPose3(X(k)), res.atVector(V(k)), res.atConstantBias(B(k))) for k in range(n)]
    # untimed polish for the agreement check: Gauss-Newton from the LM optimum, no cost tolerance
    gnp = gtsam.GaussNewtonParams()
    gnp.setMaxIterations(5)
    gnp.setRelativeErrorTol(0.0)
    gnp.setAbsoluteErrorTol(0.0)
    pol = gtsam.GaussNewtonOptimizer(graph, res, gnp).optimize()
    polished = [node_out(pol.atPose3(X(k)), pol.atVector(V(k)), pol.atConstantBias(B(k))) for k in range(n)]

    # ---- incremental: ISAM2 and the fixed-lag smoother, epoch by epoch
    def incremental(make, with_timestamps):
        solver = make()
        realtime = []
        wall = cpu = 0.0
        prev = None
        for j in range(n):
            g = gtsam.NonlinearFactorGraph()
            for f in at[j]:
                g.add(f)
            v = gtsam.Values()
            if j == 0:
                nav = gtsam.NavState(gtsam.Rot3(arr(pr["R"])), arr(pr["p"]), arr(pr["v"]))
                bias = gtsam.imuBias.ConstantBias(arr(pr["ba"]), arr(pr["bg"]))
            else:
                nav = pims[j].predict(prev[0], prev[1])
                bias = prev[1]
            v.insert(X(j), nav.pose())
            v.insert(V(j), nav.velocity())
            v.insert(B(j), bias)
            wa, ca = clock()
            if with_timestamps:
                ts = gtsam.FixedLagSmootherKeyTimestampMap()
                for key in (X(j), V(j), B(j)):
                    ts.insert((key, times[j]))
                solver.update(g, v, ts)
            else:
                solver.update(g, v)
            pose = solver.calculateEstimatePose3(X(j))
            vel = solver.calculateEstimateVector(V(j))
            b = solver.calculateEstimateConstantBias(B(j))
            wb, cb = clock()
            wall += wb - wa
            cpu += cb - ca
            prev = (gtsam.NavState(pose, vel), b)
            realtime.append(node_out(pose, vel, b))
        return solver, realtime, wall, cpu

    def best(make, ts):
        out = None
        for _ in range(rep):
            r = incremental(make, ts)
            if out is None:
                out = list(r)
            else:
                out[2], out[3] = min(out[2], r[2]), min(out[3], r[3])
        return out

    isam, isam_rt, isam_wall, isam_cpu = best(lambda: gtsam.ISAM2(gtsam.ISAM2Params()), False)
    est = isam.calculateEstimate()
    isam_final = [node_out(est.atPose3(X(k)), est.atVector(V(k)), est.atConstantBias(B(k))) for k in range(n)]
    _, ifls_rt, ifls_wall, ifls_cpu = best(
        lambda: gtsam.IncrementalFixedLagSmoother(float(d["lag_s"]), gtsam.ISAM2Params()), True)

    json.dump({
        "repeat": rep,
        "lm": {"nodes": lm_nodes, "wall_s": lm_wall, "cpu_s": lm_cpu, "iterations": opt.iterations(),
               "initial_error": initial_error, "final_error": graph.error(res),
               "polished": polished, "polished_error": graph.error(pol)},
        "isam2": {"final": isam_final, "realtime": isam_rt, "wall_s": isam_wall, "cpu_s": isam_cpu},
        "fixed_lag": {"realtime": ifls_rt, "wall_s": ifls_wall, "cpu_s": ifls_cpu},
        "n_factors": graph.size(),
    }, sys.stdout)


if __name__ == "__main__":
    main()
