"""GTSAM 4.3 peer for subnav's IMU preintegration (host/src/fgo/preintegration.rs).

stdin: JSON {"gravity": [3], "acc_cov": 3x3, "gyro_cov": 3x3, "int_cov": 3x3,
             "bias_hat": [6] (acc, gyro), "samples": [[ax, ay, az, wx, wy, wz, dt], ...],
             "predict": {"R": 3x3, "p": [3], "v": [3], "bias": [6]}}
stdout: JSON with GTSAM's PreintegratedImuMeasurements (its default, tangent-space) results.
"""
import json
import sys

import gtsam
import numpy as np


def main():
    d = json.load(sys.stdin)
    g = np.array(d["gravity"], dtype=float)
    p = gtsam.PreintegrationParams(g)
    p.setAccelerometerCovariance(np.array(d["acc_cov"], dtype=float))
    p.setGyroscopeCovariance(np.array(d["gyro_cov"], dtype=float))
    p.setIntegrationCovariance(np.array(d["int_cov"], dtype=float))
    b = np.array(d["bias_hat"], dtype=float)
    pim = gtsam.PreintegratedImuMeasurements(p, gtsam.imuBias.ConstantBias(b[:3], b[3:]))
    for s in d["samples"]:
        pim.integrateMeasurement(np.array(s[0:3]), np.array(s[3:6]), float(s[6]))
    pr = d["predict"]
    pb = np.array(pr["bias"], dtype=float)
    st = pim.predict(
        gtsam.NavState(gtsam.Rot3(np.array(pr["R"], dtype=float)), np.array(pr["p"], dtype=float), np.array(pr["v"], dtype=float)),
        gtsam.imuBias.ConstantBias(pb[:3], pb[3:]),
    )
    out = {
        "gtsam_version": getattr(gtsam, "__version__", "unknown"),
        "delta_t": pim.deltaTij(),
        "preintegrated": pim.preintegrated().tolist(),
        "delta_R": pim.deltaRij().matrix().tolist(),
        "delta_p": pim.deltaPij().tolist(),
        "delta_v": pim.deltaVij().tolist(),
        "cov": pim.preintMeasCov().tolist(),
        "residual_cov": pim.residualCovariance().tolist(),
        "predict_R": st.attitude().matrix().tolist(),
        "predict_p": np.asarray(st.position()).tolist(),
        "predict_v": np.asarray(st.velocity()).tolist(),
    }
    json.dump(out, sys.stdout)


if __name__ == "__main__":
    main()
