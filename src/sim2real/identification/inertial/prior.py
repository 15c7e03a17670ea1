"""The inertial prior's weight, chosen by cross-validation on held-out blocks of the fit runs
(:func:`choose_prior_weight`): the strongest pull towards CAD within a tolerance of the best held-out error,
the search going on past its first grid while the scores say so."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from sim2real.identification.inertial.geometry import InertialBlock
from sim2real.identification.inertial.program import _program
from sim2real.identification.inertial.rows import DesignRows, _as_rows, _column_scale, _squared_residual

# The prior's weights first tried on held-out blocks, as fractions of the noise floor's variance: from a pull the
# data always outweigh (1e-4) to one that moves the prediction by about a tenth of the floor (0.1). The search
# goes on past either edge while the held-out score says it should (choose_prior_weight), a decade at a time,
# within PRIOR_BOUNDS. A stiffer prior cannot hand a candidate a fall it did not earn: the diagnosis fits every
# candidate with the current rung's weight (sim2real.identification.sysid).
PRIOR_GRID = (1e-4, 1e-3, 1e-2, 1e-1)


PRIOR_BOUNDS = (1e-8, 1e2)


PRIOR_BLOCKS = 4


# Among weights whose held-out error is within this fraction of the best, the strongest pull to CAD wins:
# what the held-out data cannot tell apart, the CAD decides (plausible inertias at no cost in fit).
PRIOR_TOLERANCE = 0.01


def grid_around(weight: float, bounds: tuple[float, float] = PRIOR_BOUNDS) -> tuple[float, ...]:
    """A first grid of three decades centred on ``weight`` (an earlier choice), within ``bounds``."""
    return tuple(sorted({min(max(weight * factor, bounds[0]), bounds[1]) for factor in (0.1, 1.0, 10.0)}))


@dataclass
class PriorChoice:
    """The inertial prior's weight chosen on held-out blocks: ``weight`` and each ``grid`` weight's
    held-out RMS ``scores`` (fractions of the floor's variance; RMS in the data term's units), the grid in
    increasing order as searched; ``bound``: ``"weakest"`` or ``"strongest"`` when the choice sits at the
    search's bound (:data:`PRIOR_BOUNDS`: the held-out data would have gone on), else None."""

    weight: float
    grid: list[float]
    scores: list[float]
    blocks: int
    bound: str | None = None


def choose_prior_weight(
    design: np.ndarray | DesignRows,
    target: np.ndarray,
    lower: np.ndarray,
    inertial: InertialBlock,
    floor_variance: float,
    grid: Sequence[float] = PRIOR_GRID,
    blocks: int = PRIOR_BLOCKS,
    bounds: tuple[float, float] = PRIOR_BOUNDS,
) -> PriorChoice:
    """The prior's weight by cross-validation on ``blocks`` contiguous blocks of the fit rows.

    Each weight (x ``floor_variance``) is fitted on all blocks but one and scored on the one left out; the
    score is the held-out RMS over every block. Contiguous blocks in time, not random rows: neighbouring
    samples share their noise and motion, so a random split would reward fitting it. The strongest pull
    whose score is within :data:`PRIOR_TOLERANCE` of the best is chosen. The search starts on ``grid`` and
    goes past its edges a decade at a time, never beyond ``bounds``: weaker while the weakest weight scores
    best (the data still ask for freer inertias), stronger while the strongest is still within tolerance
    (the held-out data do not yet pay for the pull). So the choice is inside the searched range unless a
    bound stopped it, which :attr:`PriorChoice.bound` says.
    """
    flat, samples, joints = _as_rows(design)  # samples x joints rows
    p = flat.shape[1]
    flat_target = target.reshape(-1)
    limits = [(int(b[0]), int(b[-1]) + 1) for b in np.array_split(np.arange(samples), blocks)]
    scale = _column_scale(flat)
    program = _program(p, lower, inertial)
    terms = []
    for start, stop in limits:
        # the training rows are the blocks before and after the held one, in time order
        train = [part for part in (slice(0, start * joints), slice(stop * joints, flat.shape[0])) if part.stop > part.start]
        terms.append((program.prepare(flat, flat_target, scale, train), slice(start * joints, stop * joints)))

    def score(relative: float) -> float:
        squared = 0.0
        for term, held in terms:
            # scores compared within PRIOR_TOLERANCE (1 %): solved to 1e-6, a score moves by up to 2e-4 of itself
            solution = program.solve_prepared(term, relative * floor_variance, precise=False)
            squared += _squared_residual(flat, flat_target, held, solution.coefficients)
        return float(np.sqrt(squared / max(target.size, 1)))

    weights = sorted(float(g) for g in grid)
    scores = [score(g) for g in weights]
    bound = None
    while True:
        best = min(scores)
        if scores[0] == best and weights[0] > bounds[0] * (1 + 1e-9):
            weights.insert(0, max(weights[0] / 10.0, bounds[0]))
            scores.insert(0, score(weights[0]))
        elif scores[-1] <= best * (1.0 + PRIOR_TOLERANCE) and weights[-1] < bounds[1] * (1 - 1e-9):
            weights.append(min(weights[-1] * 10.0, bounds[1]))
            scores.append(score(weights[-1]))
        else:
            break
    best = min(scores)
    chosen_index = max(i for i, s in enumerate(scores) if s <= best * (1.0 + PRIOR_TOLERANCE))
    if scores[0] == best and chosen_index == 0 and len(weights) > 1 and weights[0] <= bounds[0] * (1 + 1e-9):
        bound = "weakest"
    elif chosen_index == len(weights) - 1 and weights[-1] >= bounds[1] * (1 - 1e-9):
        bound = "strongest"
    return PriorChoice(weights[chosen_index], weights, scores, len(limits), bound)
