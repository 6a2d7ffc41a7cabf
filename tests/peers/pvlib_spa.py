"""Peer for the solar ephemeris: pvlib 0.16.1 `solarposition.spa_python` (NREL SPA, numpy, f64).

stdin: CSV rows `unix_us,lat_deg,lon_deg,height_m,pressure_hpa,temp_c,delta_t_s` (no header).
stdout: CSV rows `apparent_zenith_deg,zenith_deg,azimuth_deg`, same order.
All instants go through one vectorized spa_python call.
"""
import sys

import numpy as np
import pandas as pd
import pvlib

rows = np.loadtxt(sys.stdin, delimiter=",", ndmin=2, dtype=np.float64)
unix_us = rows[:, 0].astype(np.int64)
times = pd.DatetimeIndex(pd.to_datetime(unix_us, unit="us", utc=True))
res = pvlib.solarposition.spa_python(
    times,
    latitude=rows[:, 1],
    longitude=rows[:, 2],
    altitude=rows[:, 3],
    pressure=rows[:, 4] * 100.0,
    temperature=rows[:, 5],
    delta_t=rows[:, 6],
    how="numpy",
)
out = np.column_stack([res["apparent_zenith"].to_numpy(), res["zenith"].to_numpy(), res["azimuth"].to_numpy()])
sys.stderr.write(f"pvlib {pvlib.__version__}: {len(out)} instants\n")
np.savetxt(sys.stdout, out, delimiter=",", fmt="%.9f")
