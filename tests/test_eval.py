"""Evaluation helpers against brute-force definitions and an analytic surface."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

import vogjax as vj
from vogjax import report as vj_eval


def pairwise_auc(scores, occupied):
    """AUC as the probability a random occupied voxel outscores a random free one (ties: 1/2)."""
    pos, neg = scores[occupied], scores[~occupied]
    greater = (pos[:, None] > neg[None, :]).sum()
    ties = (pos[:, None] == neg[None, :]).sum()
    return (greater + 0.5 * ties) / (len(pos) * len(neg))


def test_auc_equals_the_pairwise_definition():
    rng = np.random.default_rng(0)
    occupied = rng.random(600) < 0.3
    scores = np.round(np.where(occupied, rng.normal(0.7, 0.2, 600), rng.normal(0.4, 0.2, 600)), 1)  # ties
    result = vj_eval.roc(scores, occupied)
    assert result.auc == pytest.approx(pairwise_auc(scores, occupied), abs=1e-12)
    assert result.false_positive_rate[0] == 0 and result.true_positive_rate[-1] == 1
    assert np.all(np.diff(result.false_positive_rate) >= 0)
    assert vj_eval.roc(np.full(10, 0.5), np.arange(10) < 3).auc == 0.5
    assert vj_eval.roc(np.arange(10.0), np.arange(10) >= 7).auc == pytest.approx(1.0)
    with pytest.raises(ValueError, match="occupied"):
        vj_eval.roc(np.ones(3), np.ones(3, bool))


def test_rmse_of_a_shifted_noisy_plane_is_its_noise():
    rng = np.random.default_rng(1)
    walls = [
        np.c_[rng.uniform(0, 4, 3000), rng.uniform(0, 4, 3000), np.zeros(3000)],
        np.c_[np.zeros(3000), rng.uniform(0, 4, 3000), rng.uniform(0, 3, 3000)],
        np.c_[rng.uniform(0, 4, 3000), np.zeros(3000), rng.uniform(0, 3, 3000)],
    ]
    surface = np.concatenate(walls)
    noisy = surface[::3] + rng.normal(0, 0.03, (len(surface[::3]), 3))
    distance, _ = cKDTree(surface).query(noisy)
    in_place = np.sqrt(np.mean(distance**2))
    # registration removes a shift: the RMSE is that of the points where they belong
    shifted = vj_eval.reconstruction_rmse(noisy + [0.2, -0.1, 0.05], surface)
    assert shifted == pytest.approx(in_place, rel=0.05)
    assert shifted < 0.5 * np.sqrt(np.mean(cKDTree(surface).query(noisy + [0.2, -0.1, 0.05])[0] ** 2))


def test_misclassified_counts():
    a = np.array([vj.FREE, vj.OCCUPIED, vj.UNKNOWN, vj.FREE])
    b = np.array([vj.FREE, vj.FREE, vj.UNKNOWN, vj.UNKNOWN])
    assert vj_eval.misclassified(a, b) == {"voxels": 4, "misclassified": 2, "occupied_disagreements": 1}


def test_rmse_of_a_map_with_too_few_occupied_voxels_to_register_is_not_measurable():
    # a run whose map saw next to nothing as occupied (a 20,000-scan survey's standard map held
    # 2 occupied voxels) is reported as null; its evaluation used to end in ICP's refusal
    surface = np.random.default_rng(2).uniform(0, 4, (500, 3))
    for count in (0, 1, 2):
        assert vj_eval.reconstruction_rmse(surface[:count] + 0.01, surface) is None
    assert 0.0 <= vj_eval.reconstruction_rmse(surface[:50] + 0.01, surface) < 0.02  # 0.017 before registration


def test_registration_errors_name_the_arguments():
    from vogjax.report.metrics import reconstruction_rmse, register_to_surface

    surface = np.random.default_rng(0).normal(size=(50, 3))
    with pytest.raises(ValueError, match="^points must hold at least"):
        register_to_surface(surface[:2], surface)
    with pytest.raises(ValueError, match="^surface must hold at least"):
        register_to_surface(surface, surface[:2])
    with pytest.raises(ValueError, match="^surface"):
        reconstruction_rmse(surface, np.full((5, 3), np.nan))
    assert reconstruction_rmse(surface[:2], surface) is None  # too little to register: not measurable
