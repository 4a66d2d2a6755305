"""Hybrid genetic algorithm with Simplex recombination (Haro 2008, section 3; Renders & Flasse 1996).

The population is split into groups of m + 1 individuals (m parameters), which
evolve in parallel. Each generation:

1. the whole population is ranked by cost;
2. each group draws one parent from the ranked population, with probability
   proportional to rank (the best has the highest);
3. each group makes one child by discrete recombination (genes copied from a random
   member of the group), continuous recombination (genes replaced by the group's
   mean) or Simplex recombination (a Nelder-Mead step of the group, which is a
   simplex of m + 1 points: reflection, then expansion or contraction), each with
   probability 1/3; discrete and continuous children may also mutate;
4. the child replaces the worst individual of its group when it is better.

Everything happens in log-scale space within bounds, seeded for reproducibility.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from online_id.util.interrupts import interrupt_inside


@dataclass(frozen=True)
class GAConfig:
    """Settings of the hybrid GA.

    groups : number of groups of m + 1 individuals
    generations : generations to run (each costs about one evaluation per group)
    mutation_probability : chance that a discrete or continuous child mutates one gene
    mutation_std : 1σ of that mutation, as a fraction of the gene's log-range
    stall_generations : stop early when the best cost has not improved by ``stall_tolerance``
        (relative) for this many generations
    time_limit_s : stop after this wall time (None: no limit)
    """

    groups: int = 6
    generations: int = 1500
    mutation_probability: float = 0.3
    mutation_std: float = 0.05
    stall_generations: int = 300
    stall_tolerance: float = 1e-6
    time_limit_s: float | None = None


@dataclass
class GAResult:
    population: np.ndarray  # (P, m) log-scale
    costs: np.ndarray  # (P,)
    evaluations: int
    generations: int
    history: list[float] = field(default_factory=list)  # best cost per generation
    wall_s: float = 0.0
    interrupted: bool = False  # stopped by Ctrl-C (or SIGTERM/SIGHUP in the CLI): the population so far

    @property
    def best(self) -> np.ndarray:
        return self.population[int(np.argmin(self.costs))]


def hybrid_ga(cost: Callable[[np.ndarray], np.ndarray], lower: np.ndarray, upper: np.ndarray,
              config: GAConfig = GAConfig(), seed: int = 0, initial: np.ndarray | None = None,
              progress: Callable[[int, float], None] | None = None) -> GAResult:
    """Minimise ``cost`` (batch: (P, m) → (P,)) within [lower, upper]. ``initial`` rows seed the population.

    A KeyboardInterrupt between or within generations ends the search with the population so far
    (``interrupted``); one during the initial evaluation propagates (there is nothing to keep yet).
    """
    rng = np.random.default_rng(seed)
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    m = len(lower)
    size = m + 1
    P = config.groups * size
    from scipy.stats import qmc  # scipy.stats takes ~0.5 s to import: only when a fit runs

    pop = lower + (upper - lower) * qmc.LatinHypercube(d=m, seed=rng).random(P)
    if initial is not None:
        init = np.clip(np.atleast_2d(initial), lower, upper)
        pop[: len(init)] = init
    t0 = time.perf_counter()
    costs = cost(pop)
    evaluations = P
    groups = rng.permutation(P).reshape(config.groups, size)
    history, best_seen, stall = [], np.inf, 0
    span = upper - lower
    gen = 0
    interrupted = False
    try:
        for gen in range(1, config.generations + 1):
            order = np.argsort(costs)
            rank_weight = np.empty(P)
            rank_weight[order] = np.arange(P, 0, -1)
            p_select = rank_weight / rank_weight.sum()
            children = np.empty((config.groups, m))
            kinds = rng.integers(0, 3, config.groups)  # 0 discrete, 1 continuous, 2 simplex
            simplex_info = {}
            for g, members in enumerate(groups):
                parent = pop[rng.choice(P, p=p_select)]
                if kinds[g] == 2:
                    gc = costs[members]
                    worst = members[np.argmax(gc)]
                    others = members[members != worst]
                    centroid = pop[others].mean(axis=0)
                    direction = centroid - pop[worst]
                    simplex_info[g] = (centroid, direction)
                    children[g] = centroid + direction  # reflection
                else:
                    child = parent.copy()
                    genes = rng.random(m) < 0.5
                    if not genes.any():
                        genes[rng.integers(m)] = True
                    if kinds[g] == 0:
                        child[genes] = pop[rng.choice(members)][genes]
                    else:
                        child[genes] = pop[members][:, genes].mean(axis=0)
                    if rng.random() < config.mutation_probability:
                        i = rng.integers(m)
                        child[i] += rng.normal(0.0, config.mutation_std * span[i])
                    children[g] = child
            children = np.clip(children, lower, upper)
            child_costs = cost(children)
            evaluations += len(children)
            # Simplex: expansion if the reflection beat the group's best, contraction if it did not
            # beat the second worst
            second, second_idx = [], []
            for g, (centroid, direction) in simplex_info.items():
                gc = np.sort(costs[groups[g]])
                if child_costs[g] < gc[0]:
                    second.append(centroid + 2.0 * direction)
                    second_idx.append(g)
                elif child_costs[g] >= gc[-2]:
                    second.append(centroid - 0.5 * direction)
                    second_idx.append(g)
            if second:
                trial = np.clip(np.array(second), lower, upper)
                trial_costs = cost(trial)
                evaluations += len(trial)
                for g, x, c in zip(second_idx, trial, trial_costs):
                    if c < child_costs[g]:
                        children[g], child_costs[g] = x, c
            for g, members in enumerate(groups):
                worst = members[np.argmax(costs[members])]
                if child_costs[g] < costs[worst]:
                    pop[worst], costs[worst] = children[g], child_costs[g]
            best = float(costs.min())
            history.append(best)
            if progress is not None:
                progress(gen, best)
            if best < best_seen * (1 - config.stall_tolerance):
                best_seen, stall = best, 0
            else:
                stall += 1
                if stall >= config.stall_generations:
                    break
            if config.time_limit_s is not None and time.perf_counter() - t0 > config.time_limit_s:
                break
    except (KeyboardInterrupt, SystemError) as exc:
        if interrupt_inside(exc) is None:  # a SystemError not from a signal in compiled code
            raise
        # a generation changes pop and costs only in its last lines (the replacements), so what is
        # there is a population with its costs: keep it
        interrupted = True
    return GAResult(population=pop, costs=costs, evaluations=evaluations, generations=gen, history=history,
                    wall_s=time.perf_counter() - t0, interrupted=interrupted)
