"""SciPy peer for `cargo bench --bench modal` (issue 16): the 26 lowest modes (20 and six
rigid) of the free steel bar, by SciPy's `eigsh` in shift-invert mode on the matrices the
bench wrote, with largestep's shift; reports its time and the largest relative difference
of the 20 non-rigid frequencies from largestep's.

Run from the repository root after the bench:
    python3 benches/peers/scipy-eigsh/eigsh.py [target/criterion]
"""
import json
import sys
import time

import numpy as np
import scipy
import scipy.io
import scipy.sparse.linalg as sla

d = sys.argv[1] if len(sys.argv) > 1 else "target/criterion"
K = scipy.io.mmread(f"{d}/modal-bar-k.mtx").tocsc()
M = scipy.io.mmread(f"{d}/modal-bar-m.mtx").tocsc()
ours = json.load(open(f"{d}/modal-bar.json"))
times = []
for _ in range(3):
    t = time.perf_counter()
    vals = sla.eigsh(K, k=ours["modes"], M=M, sigma=ours["shift"], which="LM",
                     return_eigenvectors=False)
    times.append(time.perf_counter() - t)
vals = np.sort(vals)
freqs = np.sqrt(np.maximum(vals[6:], 0.0)) / (2 * np.pi)
diff = max(abs(a / b - 1.0) for a, b in zip(freqs, ours["frequencies_hz"]))
best = min(times)
print(f"scipy {scipy.__version__}: eigsh shift-invert, {K.shape[0]} unknowns, "
      f"best of 3 {best:.3f} s (median {sorted(times)[1]:.3f} s)")
print(f"largestep {ours['seconds']:.3f} s: {best / ours['seconds']:.1f} times faster")
print(f"largest relative difference of the 20 frequencies: {diff:.1e}")
