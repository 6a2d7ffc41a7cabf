"""GTSAM 4.3 peer for subnav's range-aided 2-D graph (host/fgo/src/range2d.rs) on a PyFactorGraph
file (e.g. GTSAM's own Data/goats_15.pyfg): the file is parsed here (independently of subnav's
reader) and solved with GTSAM's C++ factors and Levenberg-Marquardt.

- odometry: gtsam.BetweenFactorPose2 with noiseModel.Gaussian.Covariance of the file's entries;
- ranges: gtsam.RangeFactor2D (Pose2 -> Point2), sigma sqrt(variance) where the variance is the
  file's or, when given, subnav's gated one (`range_var`, file order);
- known beacons: gtsam.NonlinearEqualityPoint2 at the file's position (fixed);
  unknown beacons: free Point2 variables and a PriorFactorPose2 on the first pose (`prior0`).

stdin: {"problems": [{"file", "beacons": "known"|"unknown", "poses": [[x, y, theta]], "beacon_init": [[x, y]],
        "range_var": [..] or null, "prior0": {"mean": [x, y, theta], "sigmas": [3]} or null,
        "lm": {"max_iterations", "relative_tol", "absolute_tol"}}]}
stdout: [{"poses", "beacons", "iterations", "initial_error", "final_error", "wall_s"}] per problem
"""
import json
import sys
import time

import gtsam
import numpy as np


def parse(path):
    poses, beacons, odo, ranges = {}, {}, [], []
    with open(path) as f:
        for line in f:
            t = line.split()
            if not t:
                continue
            if t[0] == "VERTEX_SE2":
                poses[t[2]] = len(poses)
            elif t[0] == "VERTEX_XY":
                beacons[t[1]] = (len(beacons), float(t[2]), float(t[3]))
            elif t[0] == "EDGE_SE2":
                c = [float(x) for x in t[7:13]]
                cov = np.array([[c[0], c[1], c[2]], [c[1], c[3], c[4]], [c[2], c[4], c[5]]])
                odo.append((t[2], t[3], [float(x) for x in t[4:7]], cov))
            elif t[0] == "EDGE_RANGE":
                ranges.append((t[2], t[3], float(t[4]), float(t[5])))
            else:
                raise ValueError(f"{path}: unsupported line {t[0]}")
    return poses, beacons, odo, ranges


def solve(req):
    poses, beacons, odo, ranges = parse(req["file"])
    nb = len(poses)

    def xkey(name):
        return poses[name]

    def lkey(name):
        return nb + beacons[name][0]

    graph = gtsam.NonlinearFactorGraph()
    for a, b, m, cov in odo:
        graph.add(gtsam.BetweenFactorPose2(xkey(a), xkey(b), gtsam.Pose2(*m), gtsam.noiseModel.Gaussian.Covariance(cov)))
    var = req.get("range_var") or [r[3] for r in ranges]
    for (p, l, r, _), v in zip(ranges, var):
        graph.add(gtsam.RangeFactor2D(xkey(p), lkey(l), r, gtsam.noiseModel.Isotropic.Sigma(1, float(np.sqrt(v)))))
    values = gtsam.Values()
    for k, (x, y, th) in enumerate(req["poses"]):
        values.insert(k, gtsam.Pose2(x, y, th))
    for name, (k, x, y) in beacons.items():
        if req["beacons"] == "known":
            graph.add(gtsam.NonlinearEqualityPoint2(nb + k, np.array([x, y])))
            values.insert(nb + k, np.array([x, y]))
        else:
            values.insert(nb + k, np.array(req["beacon_init"][k], dtype=float))
    if req.get("prior0"):
        pr = req["prior0"]
        graph.add(gtsam.PriorFactorPose2(0, gtsam.Pose2(*pr["mean"]), gtsam.noiseModel.Diagonal.Sigmas(np.array(pr["sigmas"]))))
    lm = req["lm"]
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(lm["max_iterations"])
    params.setRelativeErrorTol(lm["relative_tol"])
    params.setAbsoluteErrorTol(lm["absolute_tol"])
    params.setlambdaInitial(1e-5)
    params.setlambdaUpperBound(1e10)
    initial_error = graph.error(values)
    t0 = time.perf_counter()
    opt = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    result = opt.optimize()
    wall = time.perf_counter() - t0
    out = {
        "poses": [[result.atPose2(k).x(), result.atPose2(k).y(), result.atPose2(k).theta()] for k in range(nb)],
        "beacons": [list(map(float, result.atPoint2(nb + k))) for k in range(len(beacons))],
        "iterations": opt.iterations(),
        "initial_error": initial_error,
        "final_error": graph.error(result),
        "wall_s": wall,
    }
    return out


def main():
    json.dump([solve(r) for r in json.load(sys.stdin)["problems"]], sys.stdout)


if __name__ == "__main__":
    main()
