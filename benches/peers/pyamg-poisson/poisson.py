"""Peers for largestep's `cargo bench --bench fluid -- poisson` (issue 17).

Reads the problem the bench writes (`target/criterion/poisson-128.bin`: n as u64, one
byte per cell kind (0 fluid, 1 solid), then the right side as f64), assembles the same
7-point matrix on the fluid cells (walls all round, open top: p = 0 half a cell above the
top row, the solid ball as walls) and solves it to a relative residual of 1e-6 with

- PyAMG's classical (Ruge-Stuben) AMG as a CG preconditioner (setup and solve timed
  apart), and
- SciPy's conjugate gradients, unpreconditioned and Jacobi-preconditioned.

Python, run beside the project: never a dependency of it.
"""

import sys
import time

import numpy as np
import pyamg
import scipy
import scipy.sparse as sp
import scipy.sparse.linalg as spla


def load(path):
    with open(path, "rb") as f:
        n = int(np.frombuffer(f.read(8), dtype="<u8")[0])
        kind = np.frombuffer(f.read(n**3), dtype=np.uint8).reshape(n, n, n)  # [k][j][i]
        b = np.frombuffer(f.read(8 * n**3), dtype="<f8").reshape(n, n, n)
    return n, kind, b


def assemble(n, kind):
    """The matrix largestep's GridPoisson applies: (d_i p_i - sum_j p_j) / h^2 over fluid
    neighbours j, d_i counting fluid neighbours and open faces (the top, y = n - 1)."""
    h = 1.0 / n
    fluid = kind == 0
    index = -np.ones(kind.shape, dtype=np.int64)
    index[fluid] = np.arange(fluid.sum())
    rows, cols, vals = [], [], []
    diag = np.zeros(kind.shape)
    for axis in range(3):
        for shift in (-1, 1):
            nb = np.roll(fluid, -shift, axis=axis)
            inside = np.ones(kind.shape, dtype=bool)
            sl = [slice(None)] * 3
            sl[axis] = -1 if shift == 1 else 0
            inside[tuple(sl)] = False
            both = fluid & nb & inside
            diag += both
            src = index[both]
            dst = np.roll(index, -shift, axis=axis)[both]
            rows.append(src)
            cols.append(dst)
            vals.append(-np.ones(src.size))
    # The open top: y is axis 1 of [k][j][i].
    top = np.zeros(kind.shape, dtype=bool)
    top[:, -1, :] = True
    diag += fluid & top
    rows.append(index[fluid])
    cols.append(index[fluid])
    vals.append(diag[fluid])
    a = sp.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
        shape=(fluid.sum(),) * 2,
    )
    return a / (h * h), fluid


def cg(a, b, m=None):
    its = [0]

    def count(_):
        its[0] += 1

    t0 = time.perf_counter()
    x, info = spla.cg(a, b, rtol=1e-6, maxiter=20000, M=m, callback=count)
    t = time.perf_counter() - t0
    r = np.linalg.norm(b - a @ x) / np.linalg.norm(b)
    return t, its[0], r, info


def main():
    path = sys.argv[1] if len(sys.argv) > 1 else "target/criterion/poisson-128.bin"
    n, kind, rhs = load(path)
    a, fluid = assemble(n, kind)
    b = rhs[fluid].copy()
    print(f"{n}^3 cells, {a.shape[0]} unknowns; scipy {scipy.__version__}, pyamg {pyamg.__version__}")
    best = {}
    for rep in range(3):
        t0 = time.perf_counter()
        ml = pyamg.ruge_stuben_solver(a)
        setup = time.perf_counter() - t0
        m = ml.aspreconditioner(cycle="V")
        solve, its, r, _ = cg(a, b, m)
        best["pyamg"] = min(best.get("pyamg", (1e9,)), (setup + solve, setup, solve, its, r))
    print("PyAMG classical AMG + CG: total {:.3f} s (setup {:.3f} s, solve {:.3f} s), {} iterations, residual {:.1e}".format(*best["pyamg"]))
    d = sp.diags(1.0 / a.diagonal())
    t, its, r, _ = cg(a, b, d)
    print(f"SciPy CG + Jacobi: {t:.3f} s, {its} iterations, residual {r:.1e}")
    t, its, r, _ = cg(a, b)
    print(f"SciPy CG: {t:.3f} s, {its} iterations, residual {r:.1e}")


if __name__ == "__main__":
    main()
