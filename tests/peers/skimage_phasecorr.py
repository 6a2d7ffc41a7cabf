"""Peer for phase correlation: scikit-image 0.26.0 `registration.phase_cross_correlation`.

argv: path n rows cols upsample [repeat]
The file holds n pairs of float64 little-endian row-major images (reference then moving).
stdout: CSV rows `shift_row,shift_col` per pair, same order.
With repeat > 0, stderr also reports the mean seconds per pair over `repeat` passes (timing for
docs/PERFORMANCE.md; run with OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 for one core).
"""
import sys
import time

import numpy as np
import skimage
from skimage.registration import phase_cross_correlation

path, n, rows, cols, up = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]), int(sys.argv[5])
repeat = int(sys.argv[6]) if len(sys.argv) > 6 else 0
imgs = np.fromfile(path, dtype="<f8").reshape(n, 2, rows, cols)
out = np.array([phase_cross_correlation(a, b, upsample_factor=up)[0] for a, b in imgs])
if repeat > 0:
    t0 = time.perf_counter()
    for _ in range(repeat):
        for a, b in imgs:
            phase_cross_correlation(a, b, upsample_factor=up)
    dt = (time.perf_counter() - t0) / (repeat * n)
    sys.stderr.write(f"skimage {skimage.__version__}: {dt * 1e6:.1f} us per pair ({rows}x{cols}, upsample {up})\n")
sys.stderr.write(f"skimage {skimage.__version__}: {n} pairs\n")
np.savetxt(sys.stdout, out, delimiter=",", fmt="%.12f")
