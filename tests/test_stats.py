"""tympani.pipeline.model.stats: the statistics the fits share, on small cases worked by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tympani.pipeline.model.stats import (
    MAX_RHO,
    cluster_covariance,
    correlation_from_covariance,
    effective_sample_size,
    gaussian_criteria,
    lag1_autocorrelation,
    least_squares_covariances,
    mad_sd,
)


def test_lag1_pools_neighbours_within_groups_only():
    r = np.array([1.0, 2.0, 3.0, -1.0, -2.0])
    g = np.array([0, 0, 0, 1, 1])
    # pairs (1,2), (2,3), (-1,-2); the step from 3 to -1 crosses groups
    assert lag1_autocorrelation(r, g, centre=False) == pytest.approx((2 + 6 + 2) / (1 + 4 + 9 + 1 + 4))
    c = r - r.mean()
    expected = (c[0] * c[1] + c[1] * c[2] + c[3] * c[4]) / np.sum(c * c)
    assert lag1_autocorrelation(r, g) == pytest.approx(expected)
    assert lag1_autocorrelation(r, np.arange(5)) == 0.0  # no neighbours share a group
    assert lag1_autocorrelation(np.zeros(4), np.zeros(4)) == 0.0


def test_lag1_of_an_ar1_series_is_its_coefficient():
    rng = np.random.default_rng(0)
    e = rng.normal(size=20_000)
    x = np.empty_like(e)
    x[0] = e[0]
    for i in range(1, e.size):
        x[i] = 0.6 * x[i - 1] + e[i]
    assert lag1_autocorrelation(x, np.zeros(x.size, int)) == pytest.approx(0.6, abs=0.02)


def test_effective_sample_size_clips_rho():
    assert effective_sample_size(100, 0.5) == pytest.approx(100 / 3)
    assert effective_sample_size(100, -0.4) == 100  # negative: as independent
    assert effective_sample_size(100, 1.0) == pytest.approx(100 * (1 - MAX_RHO) / (1 + MAX_RHO))


def test_cluster_covariance_of_a_mean_is_the_between_group_variance():
    """For a mean (X = 1, bread 1/n) the CR1 sandwich is G/(G-1) (n-1)/(n-1) Σ s_g² / n²."""
    y = np.array([1.0, 2.0, 4.0, 7.0, 3.0, 1.0])
    groups = np.array([0, 0, 1, 1, 2, 2])
    r = y - y.mean()
    cov = cluster_covariance(np.array([[1 / y.size]]), r[:, None], groups, 3)
    sums = np.bincount(groups, weights=r)
    assert cov[0, 0] == pytest.approx(3 / 2 * np.sum(sums**2) / y.size**2)


def test_least_squares_covariances_mark_an_unidentified_parameter():
    rng = np.random.default_rng(1)
    jac = rng.normal(size=(40, 3))
    jac[:, 2] = 2 * jac[:, 0]  # a direction the fit cannot see
    r = rng.normal(size=40)
    trial = np.repeat(np.arange(4), 10)
    covs, unidentified = least_squares_covariances(jac, r, trial, 0.5)
    assert unidentified.tolist() == [True, False, True]
    for cov in covs.values():
        assert math.isinf(cov[0, 0]) and np.isnan(cov[0, 1]) and np.isfinite(cov[1, 1])
    assert covs["neff"][1, 1] == pytest.approx(covs["naive"][1, 1] * 3)  # n / n_eff at rho 0.5
    corr = correlation_from_covariance(covs["naive"])
    assert corr[1, 1] == 1.0 and np.isnan(corr[0, 1]) and np.isnan(corr[1, 2])
    one_trial, _ = least_squares_covariances(jac[:, :2], r, np.zeros(40), 0.0)
    assert np.isnan(one_trial["cluster"]).all()


def test_correlation_from_covariance():
    cov = np.array([[4.0, 3.0], [3.0, 9.0]])
    assert correlation_from_covariance(cov) == pytest.approx(np.array([[1.0, 0.5], [0.5, 1.0]]))


def test_gaussian_criteria_by_hand():
    c = gaussian_criteria(rss=8.0, n=8, k=3)  # sigma² = 1
    loglik = -4.0 * (math.log(2 * math.pi) + 1.0)
    assert c.loglik == pytest.approx(loglik)
    assert c.aic == pytest.approx(6 - 2 * loglik)
    assert c.aicc == pytest.approx(c.aic + 24 / 4)
    assert c.bic == pytest.approx(3 * math.log(8) - 2 * loglik)
    assert math.isinf(gaussian_criteria(1.0, 4, 3).aicc)  # n - k - 1 = 0


def test_mad_sd():
    x = np.array([1.0, 2.0, 3.0, 4.0, 100.0])
    assert mad_sd(x) == pytest.approx(1.4826 * 1.0)  # median 3, deviations 2,1,0,1,97
    assert mad_sd(x, centre=False) == pytest.approx(1.4826 * 3.0)
    assert mad_sd(np.random.default_rng(2).normal(0, 2.0, 100_000)) == pytest.approx(2.0, rel=0.02)
