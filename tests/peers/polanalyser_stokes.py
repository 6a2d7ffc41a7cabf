"""Peer for subnav's polarization mosaic code: polanalyser (PyPI) on the same PNG.

Usage: polanalyser_stokes.py MOSAIC.png
Reads the 8/16-bit IMX250MZR mosaic with OpenCV, demosaics it with polanalyser's
COLOR_PolarMono (OpenCV bilinear Bayer demosaicing per polarizer channel), computes the linear
Stokes parameters with pa.calcStokes for polarizer angles 0/45/90/135 deg, DoLP and AoLP.
Prints JSON: width, height, full scale, and row-major s0, s1, s2, dolp, aolp (in counts / full
scale, i.e. the same [0, 1] normalisation as subnav).
"""

import json
import sys

import cv2
import numpy as np
import polanalyser as pa


def main():
    img = cv2.imread(sys.argv[1], cv2.IMREAD_UNCHANGED)
    full = 255.0 if img.dtype == np.uint8 else 65535.0
    chans = pa.demosaicing(img, pa.COLOR_PolarMono)  # [0, 45, 90, 135]
    inten = np.stack([c.astype(float) / full for c in chans])
    s = pa.calcStokes(inten, np.deg2rad([0, 45, 90, 135]))
    out = {
        "width": int(img.shape[1]),
        "height": int(img.shape[0]),
        "s0": s[..., 0].ravel().tolist(),
        "s1": s[..., 1].ravel().tolist(),
        "s2": s[..., 2].ravel().tolist(),
        "dolp": pa.cvtStokesToDoLP(s).ravel().tolist(),
        "aolp": pa.cvtStokesToAoLP(s).ravel().tolist(),
    }
    json.dump(out, sys.stdout)


if __name__ == "__main__":
    main()
