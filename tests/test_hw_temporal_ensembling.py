"""Temporal ensembling against a hand computation of ACT's weights exp(-0.01 i), i = 0 oldest."""

import math
import threading

import numpy as np
import pytest

from hardware.temporal_ensembling import TemporalEnsembler


def test_three_chunks_match_hand_computation():
    ens = TemporalEnsembler(chunk_size=4, action_dim=2)
    ens.add_chunk(0, [[0, 0], [1, 10], [2, 20], [3, 30]])
    ens.add_chunk(1, [[100, 0], [101, 0], [102, 0], [103, 0]])
    ens.add_chunk(2, [[7, 7], [8, 8], [9, 9], [10, 10]])
    # step 2 is covered by chunk@0 (index 2 -> [2, 20]), chunk@1 (index 1 -> [101, 0]), chunk@2 (index 0 -> [7, 7]);
    # weights exp(0), exp(-0.01), exp(-0.02) with the OLDEST (chunk@0) first.
    w0, w1, w2 = 1.0, math.exp(-0.01), math.exp(-0.02)
    s = w0 + w1 + w2
    expected = [(w0 * 2 + w1 * 101 + w2 * 7) / s, (w0 * 20 + w1 * 0 + w2 * 7) / s]
    np.testing.assert_allclose(ens.action(2), expected, rtol=1e-12)


def test_oldest_gets_largest_weight_with_large_k():
    ens = TemporalEnsembler(chunk_size=3, action_dim=1, k=50.0)
    ens.add_chunk(0, [[0], [1], [2]])
    ens.add_chunk(1, [[-5], [-6], [-7]])
    assert ens.action(1)[0] == pytest.approx(1.0, abs=1e-12)  # exp(-50) ~ 0 for the newer chunk


def test_k_zero_is_the_plain_mean_and_a_chunk_of_one_passes_through():
    ens = TemporalEnsembler(chunk_size=3, action_dim=1, k=0.0)
    for t0, v in ((0, 1.0), (1, 4.0), (2, 10.0)):
        ens.add_chunk(t0, [[v], [v], [v]])
    assert ens.action(2)[0] == pytest.approx(5.0, abs=1e-12)
    one = TemporalEnsembler(chunk_size=1, action_dim=2)
    for t in range(3):
        one.add_chunk(t, [[t, -t]])
        np.testing.assert_array_equal(one.action(t), [t, -t])
        assert len(one) == 1  # the chunk of the step before has expired


@pytest.mark.parametrize("k", [0.01, 1e6, 1e308])
def test_a_long_run_stays_finite_keeps_at_most_a_chunks_worth_and_never_warns(k):
    """5 000 control steps, a chunk every step: the weights never underflow to a zero sum (the oldest weighs 1),
    an extreme k overflows to weight 0 silently, and expired chunks are dropped."""
    import warnings

    ens = TemporalEnsembler(chunk_size=20, action_dim=3, k=k)
    rng = np.random.default_rng(0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for t in range(5000):
            ens.add_chunk(t, rng.normal(0, 1, (20, 3)))
            a = ens.action(t)
            assert np.isfinite(a).all() and len(ens) <= 20


def test_out_of_order_arrival_is_ordered_by_prediction_step():
    a = TemporalEnsembler(chunk_size=3, action_dim=1)
    b = TemporalEnsembler(chunk_size=3, action_dim=1)
    a.add_chunk(0, [[1], [2], [3]]); a.add_chunk(1, [[10], [20], [30]])
    b.add_chunk(1, [[10], [20], [30]]); b.add_chunk(0, [[1], [2], [3]])
    assert a.action(2)[0] == b.action(2)[0]
    assert a.action(2)[0] != pytest.approx((3 + 20) / 2)  # weights are not uniform


def test_single_chunk_passes_actions_through_and_expires():
    ens = TemporalEnsembler(chunk_size=3, action_dim=2)
    ens.add_chunk(5, np.arange(6).reshape(3, 2))
    with pytest.raises(LookupError, match="step 4"):
        ens.action(4)
    np.testing.assert_array_equal(ens.action(7), [4, 5])
    with pytest.raises(LookupError, match="step 8"):
        ens.action(8)
    assert len(ens) == 0 and not ens.covers(7)


@pytest.mark.parametrize(
    "chunk, match",
    [(np.zeros((5, 2)), "1 <= L <= 4"), (np.zeros((4, 3)), r"\(L, 2\)"), (np.zeros(4), "shape"),
     (np.array([[0.0, np.nan]]), "NaN")],
)
def test_bad_chunks_are_rejected(chunk, match):
    with pytest.raises(ValueError, match=match):
        TemporalEnsembler(chunk_size=4, action_dim=2).add_chunk(0, chunk)


@pytest.mark.parametrize("kwargs, match", [(dict(chunk_size=0, action_dim=1), "chunk_size"),
                                           (dict(chunk_size=1, action_dim=0), "action_dim"),
                                           (dict(chunk_size=1, action_dim=1, k=-1.0), "k"),
                                           (dict(chunk_size=2.7, action_dim=1), "chunk_size"),
                                           (dict(chunk_size=True, action_dim=1), "chunk_size"),
                                           (dict(chunk_size=1, action_dim=1, k=None), "k"),
                                           (dict(chunk_size=1, action_dim=1, k="0.01"), "k"),
                                           (dict(chunk_size=1, action_dim=1, k=float("inf")), "k"),
                                           (dict(chunk_size=1, action_dim=2, angle_dims=(2,)), "angle_dims"),
                                           (dict(chunk_size=1, action_dim=2, angle_dims=(0.5,)), "angle_dims"),
                                           (dict(chunk_size=1, action_dim=2, angle_dims=1), "angle_dims")])
def test_bad_construction_names_the_argument(kwargs, match):
    with pytest.raises(ValueError, match=f"^{match} must be"):
        TemporalEnsembler(**kwargs)


def test_an_angle_blends_as_a_heading_across_pi_and_as_a_number_away_from_it():
    """3.13 and -3.13 rad are one heading 0.0232 rad wide: blended near pi, not to 0 (the filter would then turn the
    wrist half a turn); votes that need no unwrapping blend exactly as numbers, so nothing else changes."""
    ens = TemporalEnsembler(2, 2, k=0.0, angle_dims=(1,))
    ens.add_chunk(0, [[0.0, 3.13], [1.0, 3.13]])
    ens.add_chunk(1, [[3.0, -3.13], [5.0, -3.13]])
    blended = ens.action(1)
    assert blended[0] == 2.0 and blended[1] == pytest.approx(np.pi, abs=1e-12)  # (3.13 + 2 pi - 3.13) / 2
    plain = TemporalEnsembler(2, 2, k=0.01)
    near = TemporalEnsembler(2, 2, k=0.01, angle_dims=(1,))
    for ens in (plain, near):
        ens.add_chunk(0, [[0.0, 0.4], [1.0, 0.5]])
        ens.add_chunk(1, [[3.0, -0.2], [5.0, 0.1]])
    assert np.array_equal(plain.action(1), near.action(1))


@pytest.mark.parametrize("t", [1.5, "1", float("nan"), None])
def test_a_step_that_is_not_an_int_is_refused_never_truncated(t):
    ens = TemporalEnsembler(chunk_size=3, action_dim=1)
    ens.add_chunk(0, [[1], [2], [3]])
    for call in (lambda: ens.add_chunk(t, [[5]]), lambda: ens.action(t), lambda: ens.covers(t)):
        with pytest.raises(ValueError, match=r"^t must be an int control step"):
            call()
    assert len(ens) == 1 and ens.action(np.int64(1))[0] == 2.0


def test_concurrent_adds_lose_nothing():
    ens = TemporalEnsembler(chunk_size=2, action_dim=1)
    threads = [threading.Thread(target=lambda s=s: ens.add_chunk(s, [[s], [s]])) for s in range(200)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    assert len(ens) == 200
    # step 10 covered by chunks @9 and @10 only; weights 1 and exp(-0.01), oldest (9) first
    w = math.exp(-0.01)
    assert ens.action(10)[0] == pytest.approx((9 + 10 * w) / (1 + w))
