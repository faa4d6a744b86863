"""CMA-ES (Hansen's covariance matrix adaptation evolution strategy), ask-and-tell, in numpy.

The standard (mu/mu_w, lambda) strategy with cumulative step-size adaptation and rank-one plus rank-mu
covariance updates, its constants as in Hansen's tutorial (arXiv:1604.00772). Small and deterministic
for a seed: the servo fit has a handful of dimensions and evaluates a population in parallel.
"""

from __future__ import annotations

import numpy as np


class CMAES:
    """Minimise over R^n from ``mean`` with step size ``sigma``: ``ask()`` a population, ``tell()`` its losses."""

    def __init__(
        self,
        mean: np.ndarray,
        sigma: float,
        population: int | None = None,
        seed: int = 0,
        covariance: np.ndarray | None = None,
    ):
        """``covariance``: the first distribution's shape (identity by default), ``sigma`` its scale."""
        n = len(mean)
        self.mean, self.sigma, self.rng = np.asarray(mean, float), float(sigma), np.random.default_rng(seed)
        self.lam = population or 4 + int(3 * np.log(n))
        self.mu = self.lam // 2
        weights = np.log(self.mu + 0.5) - np.log(np.arange(1, self.mu + 1))
        self.weights = weights / weights.sum()
        self.mueff = 1.0 / np.sum(self.weights**2)
        self.cc = (4 + self.mueff / n) / (n + 4 + 2 * self.mueff / n)
        self.cs = (self.mueff + 2) / (n + self.mueff + 5)
        self.c1 = 2 / ((n + 1.3) ** 2 + self.mueff)
        self.cmu = min(1 - self.c1, 2 * (self.mueff - 2 + 1 / self.mueff) / ((n + 2) ** 2 + self.mueff))
        self.damps = 1 + 2 * max(0.0, np.sqrt((self.mueff - 1) / (n + 1)) - 1) + self.cs
        self.chi = np.sqrt(n) * (1 - 1 / (4 * n) + 1 / (21 * n**2))
        self.pc, self.ps = np.zeros(n), np.zeros(n)
        self.cov = np.eye(n) if covariance is None else np.array(covariance, float)
        self.generation = 0
        self._steps = np.zeros((self.lam, n))

    def ask(self) -> np.ndarray:
        """The next population, (lambda, n)."""
        values, vectors = np.linalg.eigh(self.cov)
        self._basis = vectors * np.sqrt(np.maximum(values, 1e-20))
        self._steps = self.rng.standard_normal((self.lam, len(self.mean))) @ self._basis.T
        return self.mean + self.sigma * self._steps

    def tell(self, losses: np.ndarray) -> None:
        """Update from the losses of the last ``ask()``'s population."""
        n, order = len(self.mean), np.argsort(losses)
        best = self._steps[order[: self.mu]]
        step = self.weights @ best
        self.mean = self.mean + self.sigma * step
        whitened = np.linalg.solve(self._basis, step)
        self.ps = (1 - self.cs) * self.ps + np.sqrt(self.cs * (2 - self.cs) * self.mueff) * whitened
        norm = np.linalg.norm(self.ps) / np.sqrt(1 - (1 - self.cs) ** (2 * (self.generation + 1)))
        hsig = float(norm / self.chi < 1.4 + 2 / (n + 1))
        self.pc = (1 - self.cc) * self.pc + hsig * np.sqrt(self.cc * (2 - self.cc) * self.mueff) * step
        rank_mu = (best * self.weights[:, None]).T @ best
        self.cov = (
            (1 - self.c1 - self.cmu) * self.cov
            + self.c1 * (np.outer(self.pc, self.pc) + (1 - hsig) * self.cc * (2 - self.cc) * self.cov)
            + self.cmu * rank_mu
        )
        self.cov = (self.cov + self.cov.T) / 2
        self.sigma *= np.exp((self.cs / self.damps) * (np.linalg.norm(self.ps) / self.chi - 1))
        self.generation += 1
