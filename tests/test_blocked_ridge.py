"""The ceiling's pose learners choose their ridge penalty on contiguous blocks with one SVD per block
(sim2real.identification.diagnosis.blocked_ridge): the penalty, and so the fitted model, must be the one
scikit-learn's RidgeCV(cv=KFold(k)) chooses through GridSearchCV."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from sklearn.linear_model import RidgeCV
from sklearn.model_selection import KFold

from sim2real.identification.diagnosis.blocked_ridge import BlockedRidgeCV

ALPHAS = np.logspace(-3, 3, 13)


def _drifting_pose(seed: int, samples: int, features: int, noise: float) -> tuple[np.ndarray, np.ndarray]:
    """A slow motion whose later blocks visit poses the earlier ones did not, and a target linear in a few of its
    features plus noise: where the blocked search and a random one part."""
    rng = np.random.default_rng(seed)
    time = np.linspace(0.0, 1.0, samples)
    phases = rng.uniform(0, 2 * np.pi, features)
    x = np.sin(2 * np.pi * rng.uniform(0.3, 2.0, features) * time[:, None] + phases) + time[:, None] * rng.normal(size=features)
    weights = np.where(rng.random(features) < 0.4, rng.normal(size=features), 0.0)
    return x, x @ weights + noise * rng.normal(size=samples)


@settings(max_examples=15, deadline=None, derandomize=True)
@given(seed=st.integers(0, 10_000), samples=st.integers(60, 400), features=st.integers(1, 25),
       noise=st.sampled_from([0.0, 0.01, 0.3, 3.0]), blocks=st.sampled_from([3, 5]))
def test_the_blocked_search_chooses_the_penalty_and_model_gridsearch_does(seed: int, samples: int, features: int,
                                                                          noise: float, blocks: int) -> None:
    x, y = _drifting_pose(seed, samples, features, noise)
    reference = RidgeCV(alphas=ALPHAS, cv=KFold(blocks)).fit(x, y)
    blocked = BlockedRidgeCV(alphas=ALPHAS, blocks=blocks).fit(x, y)
    scores = np.sort(blocked.cv_scores_)[::-1]
    if scores.size > 1 and scores[0] - scores[1] < 1e-9 * max(1.0, abs(scores[0])):
        return  # two penalties score alike to the solver's precision: either is GridSearchCV's choice on some CPU
    assert blocked.alpha_ == reference.alpha_
    assert blocked.cv_scores_.max() == pytest.approx(reference.best_score_, rel=1e-8, abs=1e-10)
    np.testing.assert_array_equal(blocked.predict(x), reference.predict(x))


def test_a_constant_block_scores_as_r2_score_does() -> None:
    """A block whose target does not move (an arm parked for a while) scores 1 where predicted exactly, else 0."""
    x = np.column_stack([np.linspace(0, 1, 50), np.linspace(0, 1, 50) ** 2])
    y = np.concatenate([np.full(10, 2.0), np.linspace(0, 1, 40)])
    reference = RidgeCV(alphas=ALPHAS, cv=KFold(5)).fit(x, y)
    blocked = BlockedRidgeCV(alphas=ALPHAS, blocks=5).fit(x, y)
    assert blocked.alpha_ == reference.alpha_
    assert blocked.cv_scores_.max() == pytest.approx(reference.best_score_, rel=1e-8)
