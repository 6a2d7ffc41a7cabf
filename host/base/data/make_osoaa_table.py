#!/usr/bin/env python3
"""Builds osoaa_polarization.csv (our script) from the 24 OSOAA V2.0 downwelling fields of
../shared/reference/osoaa/ (see OSOAA_PROVENANCE.md): per case and grid point the normalized
Stokes q = Q/I and u = U/I in the meridian frame, for relative azimuths 0-180 deg (the fields are
mirror-symmetric about the solar plane to 2e-16: q(360-a) = q(a), u(360-a) = -u(a)).
Usage: python3 make_osoaa_table.py ../../../../shared/reference/osoaa > osoaa_polarization.csv"""
import csv, os, re, sys

src = sys.argv[1]
print("sun_zenith_deg,wind_mps,water,depth_m,view_zenith_deg,rel_azimuth_deg,q,u")
names = sorted(f for f in os.listdir(src) if re.match(r"sza\d+_wind\d+_(clear|turbid)_z\d+\.csv$", f))
assert len(names) == 24, names
def key(n):
    m = re.match(r"sza(\d+)_wind(\d+)_(clear|turbid)_z(\d+)\.csv", n)
    return (int(m[1]), int(m[2]), m[3], int(m[4]))
for n in sorted(names, key=key):
    sza, wind, water, depth = key(n)
    with open(os.path.join(src, n)) as fh:
        for row in csv.DictReader(fh):
            az = float(row["rel_azimuth_deg"])
            if az > 180.0:
                continue
            i, q, u = float(row["I"]), float(row["Q"]), float(row["U"])
            print(f"{sza},{wind},{water},{depth},{float(row['view_zenith_deg']):g},{az:g},{q / i:.5f},{u / i:.5f}")
