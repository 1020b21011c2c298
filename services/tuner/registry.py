"""The tuner's algorithms behind one signature, for equal-budget comparisons (Fig. 14).

``ALGORITHMS[name](objective, dim, budget, seed, checkpoint_path=None, progress=None)``
runs OFA, plain FA, GA or PSO with its default parameters from an integer seed.
The keyword ``checkpoint_every`` (generations between checkpoints, default 10)
is accepted by all of them as well.
"""

from __future__ import annotations

import os
from typing import Protocol

import numpy as np

from services.tuner.baselines import run_fa, run_ga, run_pso
from services.tuner.evaluation import Objective, ProgressCallback
from services.tuner.ofa import run_ofa
from services.tuner.result import OptimisationResult


class AlgorithmRunner(Protocol):
    """Uniform entry point of every registered algorithm."""

    def __call__(
        self,
        objective: Objective,
        dim: int,
        budget: int,
        seed: int,
        checkpoint_path: str | os.PathLike[str] | None = None,
        progress: ProgressCallback | None = None,
        *,
        checkpoint_every: int = 10,
    ) -> OptimisationResult: ...


def run_ofa_from_seed(
    objective: Objective,
    dim: int,
    budget: int,
    seed: int,
    checkpoint_path: str | os.PathLike[str] | None = None,
    progress: ProgressCallback | None = None,
    *,
    checkpoint_every: int = 10,
) -> OptimisationResult:
    """OFA with its default (Taguchi-chosen) parameters."""
    return run_ofa(
        objective,
        dim,
        budget,
        np.random.default_rng(seed),
        checkpoint_path=checkpoint_path,
        checkpoint_every=checkpoint_every,
        progress=progress,
    )


def run_fa_from_seed(
    objective: Objective,
    dim: int,
    budget: int,
    seed: int,
    checkpoint_path: str | os.PathLike[str] | None = None,
    progress: ProgressCallback | None = None,
    *,
    checkpoint_every: int = 10,
) -> OptimisationResult:
    """Plain FA with its default parameters, no mutation."""
    return run_fa(
        objective,
        dim,
        budget,
        np.random.default_rng(seed),
        checkpoint_path=checkpoint_path,
        checkpoint_every=checkpoint_every,
        progress=progress,
    )


def run_ga_from_seed(
    objective: Objective,
    dim: int,
    budget: int,
    seed: int,
    checkpoint_path: str | os.PathLike[str] | None = None,
    progress: ProgressCallback | None = None,
    *,
    checkpoint_every: int = 10,
) -> OptimisationResult:
    """Real-coded GA with its default parameters."""
    return run_ga(
        objective,
        dim,
        budget,
        np.random.default_rng(seed),
        checkpoint_path=checkpoint_path,
        checkpoint_every=checkpoint_every,
        progress=progress,
    )


def run_pso_from_seed(
    objective: Objective,
    dim: int,
    budget: int,
    seed: int,
    checkpoint_path: str | os.PathLike[str] | None = None,
    progress: ProgressCallback | None = None,
    *,
    checkpoint_every: int = 10,
) -> OptimisationResult:
    """Global-best PSO with its default parameters."""
    return run_pso(
        objective,
        dim,
        budget,
        np.random.default_rng(seed),
        checkpoint_path=checkpoint_path,
        checkpoint_every=checkpoint_every,
        progress=progress,
    )


ALGORITHMS: dict[str, AlgorithmRunner] = {
    "ofa": run_ofa_from_seed,
    "fa": run_fa_from_seed,
    "ga": run_ga_from_seed,
    "pso": run_pso_from_seed,
}
