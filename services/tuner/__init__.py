"""Tuner: batched, seeded, budget-exact optimisers for the OFA-fuzzy design.

The paper's orthogonal firefly algorithm (OFA) is the firefly algorithm of
eqs. 1-4 with rank-based mutation (eq. 5) and parameters chosen by a Taguchi
L25(5^6) design (Table 1). It is compared at equal evaluation budgets with
plain FA, a real-coded GA and PSO (Fig. 14), on the SNR fitness of eq. 16, and with
pure random search as the floor every one of them must clear.

Every optimiser minimises a positive cost over [0, 1]^D, evaluates each
generation as one batch, draws randomness only from an injected generator, and
can checkpoint and resume a run exactly. An algorithm object
(:class:`OrthogonalFireflyAlgorithm`, :class:`FireflyAlgorithm`, :class:`GeneticAlgorithm`,
:class:`ParticleSwarm`, :class:`RandomSearch`, each holding its parameters) says how one
generation is made;
:func:`run_population_algorithm` runs it on an objective, and :data:`ALGORITHMS` gives the
default-parameter ones a seed-based signature.

The fuzzy-tuning problem itself lives in modules imported on their own, since they
pull in the batch simulator: :mod:`services.tuner.fuzzy_encoding` (the decision
vector of a scheduler), :mod:`services.tuner.fitness` (eq. 16 through one batch
simulation), :mod:`services.tuner.fuzzy_tuning` (a resumable run on disk, Fig. 14)
and :mod:`services.tuner.cli` (``swarm tune``).
"""

from services.tuner.baselines import (
    GeneticAlgorithm,
    GeneticParameters,
    ParticleSwarm,
    ParticleSwarmParameters,
)
from services.tuner.benchmark_functions import (
    BENCHMARK_FUNCTIONS,
    ackley,
    rastrigin,
    rosenbrock,
    sphere,
)
from services.tuner.checkpoint import CheckpointMismatchError
from services.tuner.evaluation import (
    EvaluationBudget,
    Objective,
    ProgressCallback,
    snr_fitness_from_cost,
)
from services.tuner.firefly import FireflyAlgorithm, FireflyParameters
from services.tuner.generational import run_population_algorithm
from services.tuner.ofa import (
    OFAParameters,
    OrthogonalFireflyAlgorithm,
    make_ofa_trial,
    ofa_parameters_from_design,
)
from services.tuner.random_search import RandomSearch, RandomSearchParameters
from services.tuner.rank_mutation import RankMutationParameters
from services.tuner.registry import ALGORITHMS, AlgorithmRunner, seeded_runner
from services.tuner.result import ConvergenceHistory, OptimisationResult
from services.tuner.taguchi import (
    TaguchiFactor,
    TaguchiResult,
    l25_orthogonal_array,
    table1_factors,
    taguchi_design,
)

__all__ = [
    "ALGORITHMS",
    "BENCHMARK_FUNCTIONS",
    "AlgorithmRunner",
    "CheckpointMismatchError",
    "ConvergenceHistory",
    "EvaluationBudget",
    "FireflyAlgorithm",
    "FireflyParameters",
    "GeneticAlgorithm",
    "GeneticParameters",
    "OFAParameters",
    "Objective",
    "OptimisationResult",
    "OrthogonalFireflyAlgorithm",
    "ParticleSwarm",
    "ParticleSwarmParameters",
    "ProgressCallback",
    "RandomSearch",
    "RandomSearchParameters",
    "RankMutationParameters",
    "TaguchiFactor",
    "TaguchiResult",
    "ackley",
    "l25_orthogonal_array",
    "make_ofa_trial",
    "ofa_parameters_from_design",
    "rastrigin",
    "rosenbrock",
    "run_population_algorithm",
    "seeded_runner",
    "snr_fitness_from_cost",
    "sphere",
    "table1_factors",
    "taguchi_design",
]
