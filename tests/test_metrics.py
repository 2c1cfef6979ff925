"""Metric definitions against closed forms and constructed embeddings."""

import time

import numpy as np
import pytest

from stablemo.errors import StableMoError
from stablemo.eval import metrics


def test_fid_identical_sets_is_zero():
    x = np.random.default_rng(0).normal(size=(500, 8))
    assert abs(metrics.fid(x, x)) < 1e-6


def test_fid_shifted_gaussians_matches_closed_form():
    rng = np.random.default_rng(1)
    a = rng.normal(size=(4000, 4))
    shift = np.array([1.0, -2.0, 0.5, 0.0])
    # Same covariance, shifted mean: FID = ‖shift‖² exactly (sample statistics are shared).
    assert metrics.fid(a, a + shift) == pytest.approx(float(shift @ shift), abs=1e-6)
    # Scaled set: μ₂ = sμ₁, Σ₂ = s²Σ₁ → FID = (s − 1)²(‖μ₁‖² + tr Σ₁).
    s = 3.0
    mu, sigma = a.mean(0), np.cov(a, rowvar=False)
    assert metrics.fid(a, a * s) == pytest.approx((s - 1) ** 2 * (mu @ mu + np.trace(sigma)), rel=1e-6)


def test_frechet_distance_diagonal_closed_form():
    mu1, mu2 = np.zeros(3), np.array([1.0, 2.0, 2.0])
    v1, v2 = np.array([1.0, 4.0, 9.0]), np.array([4.0, 1.0, 1.0])
    expected = 9.0 + np.sum((np.sqrt(v1) - np.sqrt(v2)) ** 2)
    assert metrics.frechet_distance(mu1, np.diag(v1), mu2, np.diag(v2)) == pytest.approx(expected)


def test_r_precision_perfect_and_constructed_ranks():
    rng = np.random.default_rng(2)
    motion = rng.normal(size=(64, 16)) * 10
    res = metrics.r_precision(motion.copy(), motion)
    np.testing.assert_allclose(res.r_precision, [1, 1, 1])
    assert res.mm_dist == pytest.approx(0.0)
    # Text i sits nearest to motion i+1 (cyclic within the batch), second nearest to motion i:
    # top-1 misses everywhere, top-2 and top-3 hit everywhere.
    motion = np.eye(32) * 100.0
    text = np.roll(motion, -1, axis=0) * 0.9 + motion * 0.1
    res = metrics.r_precision(text, motion)
    np.testing.assert_allclose(res.r_precision, [0, 1, 1])
    assert res.num_items == 32


def test_r_precision_drops_incomplete_batch_and_chance_level():
    rng = np.random.default_rng(3)
    text, motion = rng.normal(size=(32 * 200 + 5, 8)), rng.normal(size=(32 * 200 + 5, 8))
    res = metrics.r_precision(text, motion)
    assert res.num_items == 32 * 200
    np.testing.assert_allclose(res.r_precision, [1 / 32, 2 / 32, 3 / 32], atol=0.012)
    with pytest.raises(StableMoError):
        metrics.r_precision(text[:10], motion[:10])


def test_mm_dist_and_diversity():
    text = np.zeros((5, 2))
    motion = np.array([[3.0, 4.0]] * 5)
    assert metrics.mm_dist(text, motion) == pytest.approx(5.0)
    # Points on two far-apart clusters: diversity is the mean distance of random pairs.
    emb = np.concatenate([np.zeros((400, 3)), np.ones((400, 3)) * [10, 0, 0]])
    d = metrics.diversity(emb, np.random.default_rng(0))
    assert 3.5 < d < 6.5  # ≈ half the pairs straddle the clusters (distance 10)
    assert metrics.diversity(np.ones((301, 3)), np.random.default_rng(0)) == 0.0
    with pytest.raises(StableMoError):
        metrics.diversity(np.ones((300, 3)), np.random.default_rng(0))


def test_multimodality_constructed():
    # Each caption's generations spread on a line of spacing 1; identical captions give 0.
    emb = np.zeros((4, 30, 2))
    assert metrics.multimodality(emb, np.random.default_rng(0)) == 0.0
    emb[:, :, 0] = np.arange(30)
    mm = metrics.multimodality(emb, np.random.default_rng(0))
    assert 5 < mm < 15  # E|i − j| for i, j uniform on 0..29 is ≈ 10
    with pytest.raises(StableMoError):
        metrics.multimodality(np.zeros((4, 5, 2)), np.random.default_rng(0))


def test_replication_interval_arithmetic():
    vals = [1.0, 2.0, 3.0, 4.0]
    iv = metrics.replication_interval(vals)
    sigma = np.sqrt(np.mean((np.array(vals) - 2.5) ** 2))  # population σ = 1.1180
    assert iv.mean == pytest.approx(2.5)
    assert iv.half_width == pytest.approx(1.96 * sigma / 2.0)
    assert str(iv) == "2.500±1.096"
    assert metrics.replication_interval([7.0] * 20).half_width == 0.0


def test_aits_excludes_warmup():
    calls = []

    def gen(text, length):
        calls.append(text)
        time.sleep(0.2 if len(calls) == 1 else 0.01)  # slow first call = model warm-up

    t = metrics.average_inference_time(gen, ["a", "b", "c"], [40, 40, 40], warmup=1)
    assert len(calls) == 4
    assert 0.005 < t < 0.1


def test_aits_resets_before_every_timed_sentence_untimed():
    events = []

    def reset():
        events.append("reset")
        time.sleep(0.2)  # not part of any sentence's time

    t = metrics.average_inference_time(lambda text, n: events.append(text), ["a", "b"], [40, 40], warmup=1,
                                       reset=reset)
    assert events == ["a", "reset", "a", "reset", "b"]
    assert t < 0.1


def test_aits_of_several_methods_runs_them_round_robin():
    events = []

    def method(name, seconds):
        def generate_one(text, n):
            events.append((name, text))
            time.sleep(seconds)
        return generate_one, lambda: events.append((name, "reset"))

    times = metrics.average_inference_times({"slow": method("slow", 0.03), "fast": method("fast", 0.0)},
                                            ["a", "b"], [40, 40], warmup=1)
    assert events == [("slow", "a"), ("fast", "a"),
                      ("slow", "reset"), ("slow", "a"), ("fast", "reset"), ("fast", "a"),
                      ("slow", "reset"), ("slow", "b"), ("fast", "reset"), ("fast", "b")]
    assert times["slow"] >= 0.03 > times["fast"]
