"""Peer for subnav's LMNN: metric-learn 0.7.0 LMNN (defaults, k = 3) on sklearn's bundled datasets.

Usage: metric_learn_lmnn.py [--no-fit] DATASET SEED [SEED ...]
  --no-fit: only the data, the splits and the Euclidean 3-NN accuracy (no metric-learn fit).
  DATASET: iris | wine | digits (shipped with scikit-learn, no download).
For each seed: stratified 70/30 split (train_test_split(stratify=y, random_state=seed)),
StandardScaler fitted on the training part, LMNN(n_neighbors=3).fit, then 3-NN accuracy on the
test part in the learned metric and in the Euclidean one, and the LMNN fit time (CPU time of this
process, `time.process_time`, so every BLAS thread is counted; the Rust test runs this with one
BLAS thread: OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1).

Prints one JSON object: the raw data (X, y) once, and per seed the training indices (the test
indices are the rest) and the peer's figures, so the Rust side fits on exactly the same split.
"""

import json
import sys
import time
import warnings

import numpy as np
from metric_learn import LMNN
from sklearn import datasets
from sklearn.model_selection import train_test_split
from sklearn.neighbors import KNeighborsClassifier
from sklearn.preprocessing import StandardScaler

LOADERS = {"iris": datasets.load_iris, "wine": datasets.load_wine, "digits": datasets.load_digits}


def knn_acc(xtr, ytr, xte, yte):
    clf = KNeighborsClassifier(n_neighbors=3).fit(xtr, ytr)
    return float((clf.predict(xte) == yte).mean())


def main():
    warnings.simplefilter("ignore", FutureWarning)
    args = sys.argv[1:]
    no_fit = "--no-fit" in args
    args = [a for a in args if a != "--no-fit"]
    name = args[0]
    seeds = [int(s) for s in args[1:]]
    x, y = LOADERS[name](return_X_y=True)
    x = x.astype(float)
    idx = np.arange(len(y))
    out = {"dataset": name, "x": x.tolist(), "y": y.astype(int).tolist(), "splits": []}
    for seed in seeds:
        tr, te = train_test_split(idx, test_size=0.3, stratify=y, random_state=seed)
        sc = StandardScaler().fit(x[tr])
        xtr, xte = sc.transform(x[tr]), sc.transform(x[te])
        split = {"seed": seed, "train": sorted(int(i) for i in tr), "euclid_acc": knn_acc(xtr, y[tr], xte, y[te])}
        if not no_fit:
            t0 = time.process_time()
            m = LMNN(n_neighbors=3).fit(xtr, y[tr])
            split["fit_s"] = time.process_time() - t0
            split["lmnn_acc"] = knn_acc(m.transform(xtr), y[tr], m.transform(xte), y[te])
            split["n_iter"] = int(m.n_iter_)
            print(f"{name} seed {seed}: {split['lmnn_acc']:.4f} in {split['fit_s']:.2f} s CPU, {split['n_iter']} iterations", file=sys.stderr)
        out["splits"].append(split)
    json.dump(out, sys.stdout)


if __name__ == "__main__":
    main()
