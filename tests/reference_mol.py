"""An independent, deliberately simple method-of-lines implementation of
docs/model.md in numpy + scipy, used to cross-check the Rust core.

It shares no code with granseg: its own constants (typed in from docs/model.md),
central face fluxes F = -w c - D dc/dz exactly as docs/model.md writes them (no
upwinding, no limiter, fine for the cell Peclet numbers of the tested cases),
point values of the quintic step as the initial condition, and scipy's BDF
with a banded Jacobian sparsity pattern.
"""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp
from scipy.sparse import diags

G, PHI, DP, H, B = 9.81, 0.60, 6.0e-3, 0.090, 0.041
MU_MIN, MU_2, I0 = np.tan(np.radians(20.90)), np.tan(np.radians(32.76)), 0.279
AREA = np.pi * (0.190**2 - 0.090**2) / 4
V0 = 23.44 * 2 * np.pi / 60 * 0.190 / 2
P_LOAD = 1.093 * G / AREA


class Reference:
    """Right-hand side of the semi-discrete model on n cells."""

    def __init__(self, rho_h, rho_l, c0, k=0.7, delta_over_H=0.18, n=300):
        self.rho_h, self.rho_l, self.c0, self.k, self.n = rho_h, rho_l, c0, k, n
        self.dz = H / n
        self.z = (np.arange(n) + 0.5) * self.dz
        zf = np.arange(1, n) * self.dz
        delta = delta_over_H * H
        self.gdot = V0 / delta * np.exp(-zf / delta)
        self.diff = B * self.gdot * DP**2
        self.n_rhs = 0

    def initial(self) -> np.ndarray:
        eps, zbar = DP / 2, (1 - self.c0) * H
        x = np.clip((self.z - zbar) / eps, -1, 1)
        u = (x + 1) / 2
        return 6 * u**5 - 15 * u**4 + 10 * u**3

    def segregation_velocity(self, c):
        """w (positive downward) at the n - 1 interior faces."""
        rho = self.rho_h * c + self.rho_l * (1 - c)
        # pressure at face i+1/2: lid + weight of cells i+1 .. n-1
        above = np.cumsum(rho[::-1])[::-1][1:]
        p = P_LOAD + G * PHI * self.dz * above
        cf = 0.5 * (c[1:] + c[:-1])
        rf = self.rho_h * cf + self.rho_l * (1 - cf)
        inertial = self.gdot * DP * np.sqrt(rf * PHI / p)
        mu = MU_MIN + (MU_2 - MU_MIN) / (I0 / inertial + 1)
        return DP**2 * G * (self.rho_h - self.rho_l) * (1 - cf) * self.gdot / (18 * self.k * mu * p)

    def rhs(self, t, c):
        self.n_rhs += 1
        w = self.segregation_velocity(c)
        cf = 0.5 * (c[1:] + c[:-1])
        flux = -w * cf - self.diff * (c[1:] - c[:-1]) / self.dz
        flux = np.concatenate(([0.0], flux, [0.0]))
        return -(flux[1:] - flux[:-1]) / self.dz

    def sparsity(self):
        n = self.n
        return diags([np.ones(n - 1), np.ones(n), np.ones(n - 1)], [-1, 0, 1], format="csc")

    def solve(self, t, rtol=1e-8, atol=1e-10, method="BDF"):
        sol = solve_ivp(self.rhs, (0, t[-1]), self.initial(), method=method, t_eval=t,
                        rtol=rtol, atol=atol, jac_sparsity=self.sparsity())
        if not sol.success:
            raise RuntimeError(sol.message)
        return sol.y.T

    def layers(self, c):
        n_t = c.shape[0]
        return c.reshape(n_t, 15, self.n // 15).mean(axis=2)
