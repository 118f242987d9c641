#!/usr/bin/env python3
"""Kernel renormalisation at no-flux walls against image blobs (issue 10).

An independent numpy prototype (not the library): 2-D unit square, Gaussian
blobs K(r) = beta/pi exp(-beta r^2) with beta = c / dr^2, dr = n^-1/2, the
entropy part of the functional F = kappa sum_i m_i log rho_i and its exact
gradient flow m_i dx_i/dt = -dF/dx_i (explicit Euler, dt = 0.25 dr^2 / kappa;
the transport term only sets the metric). Three wall treatments:

  none    rho_i = sum_j m_j K(x_i - x_j); a particle that crosses a wall is
          put back on it (the barrier's job, without its force)
  images  rho_i also sums the mirror images of every blob across the four
          walls and the four corners (exact for the square)
  renorm  rho_i / Z(x_i), Z(x) = int_Omega K(x - y) dy (erf products): the
          kernel's mass inside the square (Shepard-type renormalisation);
          crossings put back as for "none"

Measured: (a) a uniform state: random fills relaxed over 20 dr^2 / kappa,
density in strips by distance to the nearest wall over the interior density;
(b) the decay rate of the no-flux mode 1 + a cos(2 pi x) over kappa k^2.
Run: python3 scripts/renormalisation_study.py [--n 1024] [--seeds 8]
"""
import argparse
import math

import numpy as np
from scipy.special import erf


def images_of(x):
    """The 9 copies of x under the reflections of the unit square (identity first),
    with the diagonal of each reflection's Jacobian."""
    out, jac = [], []
    for sx in (0, 1, 2):  # 0: identity, 1: across x = 0, 2: across x = 1
        for sy in (0, 1, 2):
            y = x.copy()
            j = np.ones(2)
            for k, s in ((0, sx), (1, sy)):
                if s == 1:
                    y[:, k] = -x[:, k]
                    j[k] = -1.0
                elif s == 2:
                    y[:, k] = 2.0 - x[:, k]
                    j[k] = -1.0
            out.append(y)
            jac.append(j)
    return out, jac


def inside_mass(x, beta):
    """Z(x) = int_[0,1]^2 K(x - y) dy and its gradient."""
    sb = math.sqrt(beta)
    a = 0.5 * (erf(sb * (1.0 - x)) + erf(sb * x))  # per axis
    da = sb / math.sqrt(math.pi) * (np.exp(-beta * x ** 2) - np.exp(-beta * (1.0 - x) ** 2))
    z = a[:, 0] * a[:, 1]
    dz = np.stack([da[:, 0] * a[:, 1], a[:, 0] * da[:, 1]], axis=1)
    return z, dz


def energy_and_gradient(x, m, beta, kappa, mode):
    n = len(x)
    copies, jacs = (images_of(x) if mode == "images" else ([x], [np.ones(2)]))
    rho = np.zeros(n)
    pair = []
    for y, j in zip(copies, jacs):
        d = x[:, None, :] - y[None, :, :]           # x_i - y_j
        k = beta / math.pi * np.exp(-beta * np.sum(d * d, axis=2))
        rho += k @ m
        pair.append((d, k, j))
    z, dz = (inside_mass(x, beta) if mode == "renorm" else (np.ones(n), np.zeros((n, 2))))
    F = kappa * np.sum(m * np.log(rho / z))
    g = np.zeros_like(x)
    for d, k, j in pair:
        gk = -2.0 * beta * d * k[:, :, None]       # grad_x_i K(x_i - y_j)
        # own density: m_i / rho_i sum_j m_j grad K(x_i - y_j)
        g += (m / rho)[:, None] * np.einsum("ijk,j->ik", gk, m)
        # neighbours' densities: m_j / rho_j m_i d/dy_i K(x_j - y_i), y_i = R x_i
        g += m[:, None] * np.einsum("jik,j->ik", -gk, m / rho) * j[None, :]
    g = kappa * (g - m[:, None] * dz / z[:, None])
    return F, g


def step(x, m, beta, kappa, dt, mode):
    _, g = energy_and_gradient(x, m, beta, kappa, mode)
    x = x - dt * g / m[:, None]
    if mode in ("none", "renorm"):
        x = np.clip(x, 0.0, 1.0)
    else:
        x = np.abs(x)                     # reflect back across x = 0 ...
        x = np.where(x > 1.0, 2.0 - x, x)  # ... and x = 1
    return x


def check_gradient(rng):
    x = rng.uniform(0.0, 1.0, (40, 2))
    m = np.full(40, 1.0 / 40)
    for mode in ("none", "images", "renorm"):
        F, g = energy_and_gradient(x, m, 60.0, 1.0, mode)
        h, worst = 1e-6, 0.0
        for i in range(0, 40, 7):
            for k in range(2):
                xp, xm = x.copy(), x.copy()
                xp[i, k] += h
                xm[i, k] -= h
                fd = (energy_and_gradient(xp, m, 60.0, 1.0, mode)[0] - energy_and_gradient(xm, m, 60.0, 1.0, mode)[0]) / (2 * h)
                worst = max(worst, abs(fd - g[i, k]) / max(1e-12, np.abs(g).max()))
        print(f"gradient check {mode}: max |FD - exact| / max|g| = {worst:.1e}")
        assert worst < 1e-6


def profile(x, dr, nb=5):
    dist = np.min(np.concatenate([x, 1.0 - x], axis=1), axis=1)
    edges = np.arange(nb + 1) * dr
    c, _ = np.histogram(dist, bins=edges)
    area = (1.0 - 2.0 * edges[:-1]) ** 2 - (1.0 - 2.0 * edges[1:]) ** 2
    interior = (dist >= edges[-1]).sum() / (1.0 - 2.0 * edges[-1]) ** 2
    return c / area, interior


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=1024)
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--betas", default="1,2")
    a = ap.parse_args()
    rng = np.random.default_rng(1)
    check_gradient(rng)
    n, kappa = a.n, 1.0
    side = int(round(math.sqrt(n)))
    dr = 1.0 / side
    dt = 0.25 * dr * dr
    m = np.full(n, 1.0 / n)
    print(f"n = {n}, dr = {dr:.4g}, dt = 0.25 dr^2; uniform state relaxed over 20 dr^2, {a.seeds} seeds")
    for c in [float(b) for b in a.betas.split(",")]:
        beta = c / (dr * dr)
        for mode in ("none", "images", "renorm"):
            prof, inner = np.zeros(5), 0.0
            for seed in range(a.seeds):
                x = np.random.default_rng(100 + seed).uniform(0.0, 1.0, (n, 2))
                for _ in range(80):
                    x = step(x, m, beta, kappa, dt, mode)
                p, i = profile(x, dr)
                prof += p
                inner += i
            print(f"beta dr^2 = {c:g} {mode:7s} uniform: strips of dr / interior = "
                  + " ".join(f"{v / inner:.3f}" for v in prof) + f"  (on a wall: {np.sum(np.min(np.concatenate([x, 1 - x], 1), 1) < 1e-12)})")
            # Cosine mode on a cell-centred lattice, x mapped through the inverse CDF of 1 + a cos(k x).
            amp, k = 0.5, 2.0 * math.pi
            u = (np.arange(side) + 0.5) / side
            xi = u.copy()
            for _ in range(50):
                xi -= (xi + amp / k * np.sin(k * xi) - u) / (1.0 + amp * np.cos(k * xi))
            gx, gy = np.meshgrid(xi, (np.arange(side) + 0.5) / side, indexing="ij")
            x = np.stack([gx.ravel(), gy.ravel()], axis=1)
            ts, logs = [], []
            t = 0.0
            a0 = None
            while True:
                A = 2.0 * np.mean(np.exp(-0.25 * k * k / beta) * np.cos(k * x[:, 0]))
                a0 = A if a0 is None else a0
                if A < 0.05 * a0 or t > 2.0 / (kappa * k * k):
                    break
                ts.append(t)
                logs.append(math.log(A))
                x = step(x, m, beta, kappa, dt, mode)
                t += dt
            rate = -np.polyfit(ts, logs, 1)[0]
            print(f"beta dr^2 = {c:g} {mode:7s} cosine mode: rate / (kappa k^2) = {rate / (kappa * k * k):.3f}")


if __name__ == "__main__":
    main()
