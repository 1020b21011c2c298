import numpy as np

from swarm_config.metrics import MetricsConfig
from world.metrics import FormationLayout, MetricsAccumulator, fitness_snr

LAYOUT = FormationLayout(
    names=("robot1", "robot2"),
    leader_index=0,
    slot_distance_m=np.array([0.0, 1.0]),
    slot_angle_rad=np.array([0.0, np.pi]),
)
CONFIG = MetricsConfig(
    steady_state_start_s=1.0, nominal_hold_s=0.5, apf_influence_m=0.4, body_radius_m=0.3
)


NO_OBSTACLES = (np.zeros((0, 2)), np.zeros(0))


def _run(samples, obstacles=NO_OBSTACLES[0], radii=NO_OBSTACLES[1]):
    acc = MetricsAccumulator((1,), LAYOUT, obstacles, radii, CONFIG)
    for t, pose, ref in samples:
        acc.update(t, pose[None], ref)
    return acc, acc.summaries()[0]


def test_rms_over_steady_window_with_constant_offsets() -> None:
    ref = np.array([0.0, 0.0, 0.0])
    # Leader 3 cm off its reference; follower 4 cm off its slot (1 m behind the leader).
    pose = np.array([[0.03, 0.0, 0.0], [0.03 - 1.0, 0.04, 0.0]])
    samples = [(k * 0.1, pose, ref) for k in range(30)]
    samples[0] = (0.0, np.array([[5.0, 0.0, 0.0], [-1.0, 0.0, 0.0]]), ref)  # before the window
    _, summary = _run(samples)
    assert np.isclose(summary["leader_tracking_rms_m"], 0.03)
    assert np.isclose(summary["formation_rms_m"]["robot2"], 0.04)
    assert np.isclose(summary["formation_max_m"], 0.04)
    assert np.isclose(summary["min_robot_separation_m"], 1.0 - 0.6, atol=0.01)


def test_samples_near_obstacles_are_not_nominal_until_hold_expires() -> None:
    obstacles = np.array([[10.0, 0.0]])
    radii = np.array([0.1])
    samples = []
    for k in range(30):
        t = k * 0.1
        # Reference near the obstacle during [1.0, 1.5) s, far otherwise.
        ref = np.array([9.5, 0.0, 0.0]) if 1.0 <= t < 1.5 else np.array([0.0, 0.0, 0.0])
        err = 0.5 if 1.0 <= t < 2.0 else 0.01
        pose = np.array([ref + [err, 0, 0], [ref[0] + err - 1.0, 0.0, 0.0]])
        samples.append((t, pose, ref))
    _, summary = _run(samples, obstacles, radii)
    # Nominal resumes 0.5 s after the reference leaves the zone at 1.5 s: t >= 1.9 (to round-off)
    assert np.isclose(summary["nominal_share"]["robot1"], 11 / 20, atol=0.051)
    assert summary["leader_tracking_rms_all_m"] > 0.2
    assert summary["leader_tracking_rms_m"] < 0.2


def test_collisions_count_contact_onsets_once() -> None:
    acc = MetricsAccumulator((1,), LAYOUT, np.zeros((0, 2)), np.zeros(0), CONFIG)
    ref = np.zeros(3)
    pose = np.array([[0.0, 0.0, 0.0], [-1.0, 0.0, 0.0]])
    touching = np.array([[[False, True], [True, False]]])
    apart = np.zeros((1, 2, 2), dtype=bool)
    for contacts in (apart, touching, touching, apart, touching):
        acc.update(0.0, pose[None], ref, contacts)
    assert acc.summaries()[0]["collisions"] == 2


def test_fitness_is_larger_for_smaller_errors_and_fewer_rules() -> None:
    assert fitness_snr(0.01, 147, 1.0, 1e-4) > fitness_snr(0.02, 147, 1.0, 1e-4)
    assert fitness_snr(0.01, 27, 1.0, 1e-4) > fitness_snr(0.01, 147, 1.0, 1e-4)
    assert np.isclose(fitness_snr(0.1, 0, 1.0, 1e-4), 10.0)


THREE = FormationLayout(
    names=("robot1", "robot2", "robot3"),
    leader_index=0,
    slot_distance_m=np.array([0.0, 1.0, 1.0]),
    slot_angle_rad=np.array([0.0, np.pi, np.pi / 2]),
)


def test_tracking_is_measured_against_whoever_leads_and_changes_are_events() -> None:
    """robot1 leads (3 cm off the trajectory) until t = 2 s, then robot2 leads (5 cm off);
    robot3 keeps its slot relative to the acting leader (2 cm off it), robot1 takes robot2's
    old slot (1 m behind, 4 cm off it)."""
    acc = MetricsAccumulator((), THREE, *NO_OBSTACLES, CONFIG)
    ref = np.array([0.0, 0.0, 0.0])
    for k in range(40):
        t_s = k * 0.1
        if t_s < 2.0:
            pose = np.array([[0.03, 0.0, 0.0], [-0.97, 0.0, 0.0], [0.03, 1.02, 0.0]])
        else:
            if acc.leader_index == 0:
                acc.set_leader(1, 1, t_s)
            pose = np.array([[-0.99, 0.0, 0.0], [0.05, 0.0, 0.0], [0.05, 1.02, 0.0]])
        acc.update(t_s, pose, ref)
    summary = acc.summaries()[0]
    # Steady window from 1 s: 10 samples led by robot1, 20 by robot2.
    expected_lead_m = np.sqrt((10 * 0.03**2 + 20 * 0.05**2) / 30)
    assert np.isclose(summary["leader_tracking_rms_m"], expected_lead_m)
    assert np.isclose(summary["formation_rms_m"]["robot3"], 0.02)
    assert np.isclose(summary["formation_rms_m"]["robot1"], 0.04)  # only while it followed
    assert np.isclose(summary["formation_rms_m"]["robot2"], 0.0)  # only before the change
    assert summary["events"] == [
        {"t_s": 2.0, "kind": "leader_change", "from": "robot1", "to": "robot2", "term": 1}
    ]


def test_a_fixed_leader_gives_no_events_and_the_old_figures() -> None:
    acc = MetricsAccumulator((), THREE, *NO_OBSTACLES, CONFIG)
    pose = np.array([[0.03, 0.0, 0.0], [-0.97, 0.04, 0.0], [0.03, 1.0, 0.0]])
    for k in range(20):
        acc.update(k * 0.1, pose, np.zeros(3))
    acc.set_leader(0, 0, 2.0)
    summary = acc.summaries()[0]
    assert summary["events"] == []
    assert np.isclose(summary["leader_tracking_rms_m"], 0.03)
    assert set(summary["formation_rms_m"]) == {"robot2", "robot3"}
    assert np.isclose(summary["formation_rms_m"]["robot2"], 0.04)


def test_leader_and_events_survive_export_and_import() -> None:
    acc = MetricsAccumulator((), THREE, *NO_OBSTACLES, CONFIG)
    acc.set_leader(2, 3, 5.0)
    copy = MetricsAccumulator((), THREE, *NO_OBSTACLES, CONFIG)
    copy.import_state(acc.export_state())
    assert (copy.leader_index, copy.leader_term, copy.events) == (2, 3, acc.events)
