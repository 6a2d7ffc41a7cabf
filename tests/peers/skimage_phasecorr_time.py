"""Speed reference for docs/PERFORMANCE.md: scikit-image 0.26.0 phase_cross_correlation on one core.

usage: skimage_phasecorr_time.py OUT_DIR SIZE UPSAMPLE REPEAT
Writes OUT_DIR/a.png and OUT_DIR/b.png (SIZE x SIZE 8-bit texture and a sub-pixel Fourier-shifted,
noisy copy; seed fixed), then times phase_cross_correlation on the images as read back from the
PNGs (float64, /255, like `subnav phasecorr` reads them) and prints the mean time per pair.
Run with OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 for one core.
"""
import os
import sys
import time

import numpy as np
import skimage
from scipy.ndimage import fourier_shift
from skimage.io import imread, imsave
from skimage.registration import phase_cross_correlation

out, size, up, repeat = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
os.makedirs(out, exist_ok=True)
rng = np.random.default_rng(2026)
y, x = np.mgrid[0:size, 0:size]
img = sum(rng.uniform(0.2, 1) * np.cos(rng.uniform(-0.4, 0.4) * y + rng.uniform(-0.4, 0.4) * x + rng.uniform(0, 6.3)) for _ in range(16))
img = img + 0.5 * rng.random(img.shape)
shifted = np.fft.ifftn(fourier_shift(np.fft.fftn(img), (3.37, -5.81))).real + 0.1 * rng.standard_normal(img.shape)
lo, hi = min(img.min(), shifted.min()), max(img.max(), shifted.max())
to8 = lambda a: np.clip(np.round(255 * (a - lo) / (hi - lo)), 0, 255).astype(np.uint8)
imsave(os.path.join(out, "a.png"), to8(img), check_contrast=False)
imsave(os.path.join(out, "b.png"), to8(shifted), check_contrast=False)
a = imread(os.path.join(out, "a.png")).astype(np.float64) / 255.0
b = imread(os.path.join(out, "b.png")).astype(np.float64) / 255.0
shift = phase_cross_correlation(a, b, upsample_factor=up)[0]
t0 = time.process_time()  # CPU time: independent of other load on the machine
for _ in range(repeat):
    phase_cross_correlation(a, b, upsample_factor=up)
dt = (time.process_time() - t0) / repeat
print(f"skimage {skimage.__version__}: shift {shift[0]:.4f} {shift[1]:.4f}, {dt * 1e6:.1f} us CPU per pair ({size}x{size}, upsample {up}, {repeat} repeats)")
