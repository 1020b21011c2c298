import numpy as np
import pytest
from pydantic import ValidationError

from swarm_config.radio import PROFILES, BurstLoss, LinkProfile
from world.radio import RowDraw, draw_links


def test_bernoulli_loss_and_delay_match_profile() -> None:
    rng = np.random.default_rng(12)
    profile = PROFILES["lossy"]
    draw = draw_links(profile, np.zeros(200_000, dtype=bool), None, rng)
    assert abs(draw.delivered.mean() - 0.8) < 0.005
    assert abs(draw.delay_s.mean() - 0.050) < 0.0005
    assert draw.delay_s.min() >= 0.030 and draw.delay_s.max() <= 0.070


def test_burst_loss_reaches_its_stationary_rate_and_clusters() -> None:
    rng = np.random.default_rng(13)
    burst = BurstLoss(good_to_bad=0.05, bad_to_good=0.25, loss_in_bad=1.0)
    profile = LinkProfile(burst=burst)
    state = np.zeros(2000, dtype=bool)
    lost = []
    for _ in range(300):
        draw = draw_links(profile, state, None, rng)
        state = draw.in_bad_state
        lost.append(~draw.delivered)
    lost_arr = np.array(lost)
    assert abs(lost_arr.mean() - burst.stationary_loss) < 0.01
    # Losses cluster: a loss is followed by a loss far more often than the average rate.
    after_loss = lost_arr[1:][lost_arr[:-1]].mean()
    assert after_loss > 2 * lost_arr.mean()


def test_range_limit_drops_long_links() -> None:
    profile = LinkProfile(range_m=2.0)
    draw = draw_links(
        profile, np.zeros(2, dtype=bool), np.array([1.0, 3.0]), np.random.default_rng(0)
    )
    np.testing.assert_array_equal(draw.delivered, [True, False])


def test_invalid_profiles_are_rejected() -> None:
    with pytest.raises(ValidationError):
        LinkProfile(loss=1.5)
    with pytest.raises(ValidationError):
        LinkProfile(loss=0.1, burst=BurstLoss(good_to_bad=0.1, bad_to_good=0.1))


@pytest.mark.parametrize("name", sorted(PROFILES))
def test_one_row_draw_equals_draw_links_frame_after_frame(name: str) -> None:
    """The world's per-frame draw (`RowDraw`) gives `draw_links`' fates and burst states bit
    for bit, over a stream of frames from changing senders, from generators in one state."""
    profile = PROFILES[name]
    robots = 5
    row = RowDraw(profile, robots)
    fast_rng, plain_rng = np.random.default_rng(41), np.random.default_rng(41)
    fast_bad = np.zeros((robots, robots), dtype=bool)
    plain_bad = fast_bad.copy()
    delivered_any = lost_any = False
    for frame in range(400):
        sender = (frame * 3) % robots
        delivered, delay_s, bad = row(fast_bad[sender], fast_rng)
        fast_bad[sender] = bad
        want = draw_links(profile, plain_bad[sender : sender + 1], None, plain_rng)
        plain_bad[sender] = want.in_bad_state[0]
        np.testing.assert_array_equal(delivered, want.delivered[0])
        np.testing.assert_array_equal(delay_s, want.delay_s[0])
        np.testing.assert_array_equal(bad, want.in_bad_state[0])
        delivered_any |= bool(delivered.any())
        lost_any |= bool((~delivered).any())
    assert delivered_any
    assert lost_any == (profile.loss > 0 or profile.burst is not None)
    assert fast_rng.random() == plain_rng.random()  # the same number of draws


def test_a_ranged_profile_is_not_drawn_by_row() -> None:
    with pytest.raises(ValueError, match="ranged"):
        RowDraw(LinkProfile(range_m=2.0), 3)
