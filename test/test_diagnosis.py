"""Observer, detection, isolation and the words of the diagnosis, on controlled inputs."""

from __future__ import annotations

import numpy as np
import pytest

from multirotor_ros.diagnosis.detection import DetectionSettings, FaultDetector, coaxial_partners
from multirotor_ros.diagnosis.diagnoser import RotorDiagnoser, rotor_reports
from multirotor_ros.diagnosis.observer import SuperTwistingObserver, levant_gains
from multirotor_ros.diagnosis.residuals import stopped_rotor_scales
from multirotor_ros.diagnosis.stopped import StoppedRotorTest, StopTestSettings
from multirotor_ros.model import state as S
from multirotor_ros.model.airframe import load_airframe
from multirotor_ros.model.integrator import Integrator
from multirotor_ros.model.model import Model


def _run_observer(observer, disturbance, noise, rng, dt=0.01, steps=300):
    y = np.zeros((1, 1))
    estimates = []
    for k in range(steps):
        y = y + dt * disturbance(k * dt)
        estimates.append(observer.update(dt, y + noise * rng.standard_normal((1, 1)), np.zeros((1, 1)))[0, 0])
    return np.array(estimates)


def test_super_twisting_observer_converges_to_a_step_and_follows_a_ramp():
    lam, alpha = levant_gains([7.6 / 0.15])
    observer = SuperTwistingObserver(lam, alpha, filter_time_constant_s=0.03)
    step = _run_observer(observer, lambda t: 7.6 if t >= 1.0 else 0.0, 0.002, np.random.default_rng(0))
    # Before the step the estimate is the noise; a step of D is followed at about D/alpha.
    assert np.abs(step[20:100]).max() < 0.1 * 7.6
    assert step[100 + 30] > 0.5 * 7.6
    assert np.abs(step[-50:].mean() - 7.6) < 0.03 * 7.6
    observer = SuperTwistingObserver(lam, alpha, filter_time_constant_s=0.03)
    ramp = _run_observer(observer, lambda t: 2.0 * t, 0.0, np.random.default_rng(1))
    assert ramp[-1] == pytest.approx(2.0 * 2.99, rel=0.05)


def test_observer_refuses_inconsistent_gains_and_measurements():
    with pytest.raises(ValueError, match="positive and finite"):
        levant_gains([1.0, -1.0])
    with pytest.raises(ValueError, match="one value per channel"):
        SuperTwistingObserver([1.0, 2.0], [1.0])
    observer = SuperTwistingObserver([1.0], [1.0])
    with pytest.raises(ValueError, match="2 channels, the observer 1"):
        observer.reset(np.zeros((1, 2)))


def test_coaxial_partners_of_the_reference_airframes():
    assert coaxial_partners(load_airframe("x8_octorotor")).tolist() == [1, 0, 3, 2, 5, 4, 7, 6]
    assert coaxial_partners(load_airframe("hexarotor_f550")).tolist() == [-1] * 6


def _signatures(airframe, omega):
    return (airframe.allocation * omega**2)[None]


def _detector_run(airframe, faulty, loss, noise_scale, rng, settings=None, steps=400, onset=200, dt=0.01):
    """Synthetic wrench residuals: noise, then -loss * signature of ``faulty`` from ``onset``."""
    omega = np.full(airframe.n_rotors, Model(airframe).hover_speed_rad_s())
    signatures = _signatures(airframe, omega)
    _, scale = stopped_rotor_scales(Model(airframe))
    detector = FaultDetector(scale, coaxial_partners(airframe), 1, settings)
    outputs = []
    for k in range(steps):
        residual = noise_scale * scale * rng.standard_normal(4)
        if k >= onset:
            residual = residual - loss * signatures[0, :, faulty]
        outputs.append(detector.update(k * dt, dt, residual[None], signatures))
    return detector, outputs


@pytest.mark.parametrize("airframe_name", ["x8_octorotor", "hexarotor_f550"])
@pytest.mark.parametrize("faulty", [0, 1, 4])
def test_detector_isolates_the_rotor_and_estimates_its_effectiveness(airframe_name, faulty):
    airframe = load_airframe(airframe_name)
    _, outputs = _detector_run(airframe, faulty, 0.6, 0.01, np.random.default_rng(faulty))
    assert not any(o.alarm[0] for o in outputs[:200])
    alarmed = [k for k, o in enumerate(outputs) if o.alarm[0]]
    assert alarmed and alarmed[0] - 200 <= 10  # persistence 0.05 s at 100 Hz, plus a sample
    final = outputs[-1]
    assert final.rotor[0] == faulty
    assert final.effectiveness[0, faulty] == pytest.approx(0.4, abs=0.03)
    assert np.all(np.delete(final.effectiveness[0], faulty) == 1.0)


def test_threshold_adapts_to_the_residual_noise():
    airframe = load_airframe("hexarotor_f550")
    quiet, _ = _detector_run(airframe, 0, 0.0, 0.01, np.random.default_rng(1), steps=300)
    noisy, _ = _detector_run(airframe, 0, 0.0, 0.1, np.random.default_rng(1), steps=300)
    ratio = noisy.noise_std / quiet.noise_std
    np.testing.assert_allclose(ratio, 10.0, rtol=0.25)
    # A 25 % loss stands out of the quiet residual but not of one ten times noisier.
    _, quiet_run = _detector_run(airframe, 2, 0.25, 0.01, np.random.default_rng(2))
    _, noisy_run = _detector_run(airframe, 2, 0.25, 0.1, np.random.default_rng(2))
    assert quiet_run[-1].alarm[0]
    assert not any(o.alarm[0] for o in noisy_run)


def test_alarm_clears_when_the_rotor_recovers():
    airframe = load_airframe("hexarotor_f550")
    omega = np.full(6, Model(airframe).hover_speed_rad_s())
    signatures = _signatures(airframe, omega)
    _, scale = stopped_rotor_scales(Model(airframe))
    detector = FaultDetector(scale, coaxial_partners(airframe), 1, DetectionSettings(clear_s=0.5))
    rng = np.random.default_rng(3)
    history = []
    for k in range(500):
        residual = 0.01 * scale * rng.standard_normal(4)
        if 150 <= k < 250:
            residual = residual - signatures[0, :, 3]
        history.append(detector.update(k * 0.01, 0.01, residual[None], signatures).alarm[0])
    assert history[200] and not history[140]
    assert not history[-1]
    assert 300 <= history.index(False, 250) <= 330  # cleared 0.5 s after the residual went away


def test_a_stopped_rotor_left_out_to_idle_stays_diagnosed_as_sure_as_its_evidence():
    # A fault-tolerant controller leaves the stopped rotor out: it idles at a tenth of its hover speed, so
    # its signature (omega²) is a hundredth and the residual says nothing about it. Before the fix that
    # silence cleared the alarm after clear_s (the stopped rotor reported OK, the demo's "all rotors OK").
    airframe = load_airframe("x8_octorotor")
    hover = np.full(8, Model(airframe).hover_speed_rad_s())
    idle = hover.copy()
    idle[2] = 0.1 * hover[2]
    _, scale = stopped_rotor_scales(Model(airframe))
    detector = FaultDetector(scale, coaxial_partners(airframe), 1, DetectionSettings(clear_s=0.5))
    diagnoser_view = RotorDiagnoser(Model(airframe))
    rng = np.random.default_rng(4)
    outputs = []
    for k in range(600):
        omega = hover if k < 250 else idle
        signatures = _signatures(airframe, omega)
        residual = 0.01 * scale * rng.standard_normal(4)
        if k >= 150:  # rotor 3 stopped: the whole of its commanded thrust is missing
            residual = residual - signatures[0, :, 2]
        outputs.append(detector.update(k * 0.01, 0.01, residual[None], signatures))
    at_idle_start, last = outputs[249], outputs[-1]
    assert at_idle_start.alarm[0] and at_idle_start.rotor[0] == 2
    assert last.alarm[0] and last.rotor[0] == 2 and not last.partner_ambiguous[0]
    # The estimate and its standard deviation are those of the evidence, not of the idle samples.
    assert last.effectiveness[0, 2] == at_idle_start.effectiveness[0, 2] < 0.05
    assert last.effectiveness_std[0, 2] == at_idle_start.effectiveness_std[0, 2] < 0.05
    assert last.loss_std[0, 2] > 50 * last.effectiveness_std[0, 2]
    diagnoser_view.last = last
    estimate, std = diagnoser_view.effectiveness()
    assert estimate[2] < 0.05 and std[2] < 0.05 and np.all(np.delete(estimate, 2) == 1.0)
    (report,) = [r for r in rotor_reports(last, 8, coaxial_partners(airframe), 0.5) if r.name == "rotor_3"]
    assert report.level == "ERROR" and "stopped" in report.message


# Noise of the raw (one-interval) wrench residual, in stopped rotors per channel (thrust, roll, pitch, yaw):
# about what the in-loop flights show (velocity-derived thrust and gyro-derived yaw are weak channels).
RAW_NOISE = np.array([2.0, 0.07, 0.07, 2.0])


def _stop_test_run(airframe, faulty, loss, seed, onset=60, steps=100, dt=0.01, noise=RAW_NOISE, speeds=None):
    """Raw residuals: noise, then -loss * signature of ``faulty`` from ``onset``; the test's verdicts.

    ``speeds``: rotor speeds over the hover speed (all 1 by default).
    """
    omega = Model(airframe).hover_speed_rad_s() * (np.ones(airframe.n_rotors) if speeds is None else speeds)
    signatures = _signatures(airframe, omega)
    _, scale = stopped_rotor_scales(Model(airframe))
    rng = np.random.default_rng(seed)
    test = StoppedRotorTest(scale, coaxial_partners(airframe))
    verdicts = []
    for k in range(steps):
        residual = noise * scale * rng.standard_normal(4)
        if k >= onset:
            residual = residual - loss * signatures[0, :, faulty]
        calm = np.array([k < onset])  # the detector suspects nothing before the fault
        verdicts.append(
            test.update(
                k * dt, dt, residual[None], signatures, np.zeros((1, 4)), calm, np.ones(1, dtype=bool)
            )
        )
    return verdicts


@pytest.mark.parametrize("faulty", [0, 3])
def test_the_stop_test_names_a_stopped_rotor_within_four_samples_and_nothing_before(faulty):
    for seed in range(10):
        verdicts = _stop_test_run(load_airframe("hexarotor_f550"), faulty, 1.0, seed)
        assert not any(v.stopped[0] for v in verdicts[:60])
        first = next(k for k, v in enumerate(verdicts) if v.stopped[0])
        assert first <= 63 and verdicts[first].rotor[0] == faulty
        assert verdicts[first].loss_std[0] <= StopTestSettings().max_loss_std


@pytest.mark.parametrize("airframe_name", ["x8_octorotor", "hexarotor_f550"])
@pytest.mark.parametrize("loss", [0.5, 0.7])
def test_the_stop_test_takes_no_partial_loss_for_a_stop(airframe_name, loss):
    for seed in range(10):
        verdicts = _stop_test_run(load_airframe(airframe_name), 2, loss, seed)
        assert not any(v.stopped[0] for v in verdicts)


@pytest.mark.parametrize(
    ("thrust_noise", "seen_loss", "named_at_least"),
    [(RAW_NOISE[0], 1.0, 5), (0.03, 0.92, 0)],
    ids=["velocity", "imu"],
)
def test_the_stop_test_never_names_the_coaxial_partner_of_a_stopped_rotor(
    thrust_noise, seen_loss, named_at_least
):
    # On the X8 only the weak yaw channel tells rotor 3 from rotor 4: a verdict comes later, or not at all
    # (the detector's alarm then stands alone), but it never names the partner. Not even when the thrust
    # is measured precisely (an IMU), the partner turns 4 % slower and the model sees 92 % of the stop
    # (the fault's first samples): the partner's smaller signature then fits thrust, roll and pitch
    # better, and judged on them the identifier's replay named rotor 4.
    speeds = np.ones(8)
    speeds[3] = 0.96
    noise = np.array([thrust_noise, *RAW_NOISE[1:]])
    named = [
        next(
            (
                int(v.rotor[0])
                for v in _stop_test_run(
                    load_airframe("x8_octorotor"), 2, seen_loss, seed, noise=noise, speeds=speeds
                )
                if v.stopped[0]
            ),
            None,
        )
        for seed in range(10)
    ]
    assert set(named) <= {2, None} and named.count(2) >= named_at_least


def test_the_stop_test_says_nothing_before_it_has_learnt_the_noise():
    verdicts = _stop_test_run(load_airframe("hexarotor_f550"), 0, 1.0, 0, onset=40)
    learn = StopTestSettings()
    # Samples teach the noise learn_after_s after they came: 25 calm ones have not done so by the onset.
    assert 40 * 0.01 < learn.learn_after_s + learn.learn_samples * 0.01
    assert not any(v.stopped[0] for v in verdicts)


def test_stop_test_settings_refuse_nonsense():
    with pytest.raises(ValueError, match="window_s"):
        StopTestSettings(window_s=0.0)
    with pytest.raises(ValueError, match="partial_loss"):
        StopTestSettings(partial_loss=1.0)
    with pytest.raises(ValueError, match="whole numbers"):
        StopTestSettings(min_samples=2.5)
    with pytest.raises(ValueError, match="wrench_scale"):
        StoppedRotorTest(np.ones(3), [-1] * 4)
    with pytest.raises(ValueError, match="partners"):
        StoppedRotorTest(np.ones(4), [1, 0, 3, 8])


def test_a_declared_stop_is_not_pulled_back_by_the_observer_ramp_and_clears_on_evidence():
    # The fast test declares rotor 2 stopped; the observer's residual then ramps (here: stays at half the
    # loss) for longer than no_evidence_s would allow. During no_evidence_s it moves nothing; afterwards a
    # rotor that turns out healthy (residual back to noise) clears the alarm after clear_s, as usual.
    airframe = load_airframe("hexarotor_f550")
    settings = DetectionSettings(clear_s=0.3)
    detector, signatures, scale = _learnt_detector(airframe, np.random.default_rng(6), settings=settings)
    rng = np.random.default_rng(7)
    detector.declare_stopped(2.0, np.array([True]), np.array([2]), np.array([0.03]), no_evidence_s=0.45)
    outputs = []
    for k in range(100):
        t = 2.0 + 0.01 * k
        residual = 0.01 * scale * rng.standard_normal(4)
        if t < 2.45:
            residual = residual - 0.5 * signatures[0, :, 2]
        outputs.append(detector.update(t, 0.01, residual[None], signatures))
    during = outputs[:45]
    assert all(o.alarm[0] and o.rotor[0] == 2 and o.onset_t[0] == 2.0 for o in during)
    assert all(
        o.effectiveness[0, 2] == 0.0 and o.effectiveness_std[0, 2] == pytest.approx(0.03) for o in during
    )
    assert not outputs[-1].alarm[0]


def test_a_second_stop_of_another_coaxial_pair_is_kept_beside_the_alarm_but_not_the_partners():
    # X8 (0-based): rotor 2 stops, then rotor 5 (another pair); rotor 3 is rotor 2's coaxial partner.
    # All within rotor 2's no-evidence time, so that the synthetic residual moves no estimate.
    airframe = load_airframe("x8_octorotor")
    detector, signatures, scale = _learnt_detector(airframe, np.random.default_rng(8))
    one = np.array([True])
    detector.declare_stopped(2.0, one, np.array([2]), np.array([0.03]), no_evidence_s=0.45)
    detector.declare_stopped(2.1, one, np.array([3]), np.array([0.04]), no_evidence_s=0.45)
    detector.declare_stopped(2.2, one, np.array([5]), np.array([0.05]), no_evidence_s=0.45)
    rng = np.random.default_rng(9)
    output = detector.update(2.21, 0.01, (0.01 * scale * rng.standard_normal(4))[None], signatures)
    assert output.alarm[0] and output.rotor[0] == 2 and output.onset_t[0] == 2.0
    assert np.flatnonzero(output.also_stopped[0]).tolist() == [5]
    assert output.effectiveness[0].tolist() == [1, 1, 0, 1, 1, 0, 1, 1]
    assert output.effectiveness_std[0, 5] == pytest.approx(0.05)
    reports = rotor_reports(output, 8, coaxial_partners(airframe), 0.5)
    assert [r.level for r in reports] == ["OK", "OK", "ERROR", "OK", "OK", "ERROR", "OK", "OK"]
    assert reports[5].message.startswith("rotor 6 stopped or lost its propeller too")


def test_an_airframe_without_coaxial_pairs_keeps_no_second_stop():
    airframe = load_airframe("hexarotor_f550")
    detector, signatures, scale = _learnt_detector(airframe, np.random.default_rng(8))
    one = np.array([True])
    detector.declare_stopped(2.0, one, np.array([0]), np.array([0.03]), no_evidence_s=0.45)
    detector.declare_stopped(2.1, one, np.array([3]), np.array([0.03]), no_evidence_s=0.45)
    output = detector.update(2.11, 0.01, (0.01 * scale)[None], signatures)
    assert output.rotor[0] == 0 and not output.also_stopped.any() and output.effectiveness[0, 3] == 1.0


def test_a_stop_beside_a_partial_loss_is_not_kept():
    # Partial losses stay one per vehicle: only a declared stop takes a second stopped rotor beside it.
    airframe = load_airframe("x8_octorotor")
    detector, outputs = _detector_run(airframe, 4, 0.5, 0.01, np.random.default_rng(5))
    assert outputs[-1].alarm[0] and outputs[-1].rotor[0] == 4
    detector.declare_stopped(4.0, np.array([True]), np.array([0]), np.array([0.03]), no_evidence_s=0.45)
    _, scale = stopped_rotor_scales(Model(airframe))
    omega = np.full(airframe.n_rotors, Model(airframe).hover_speed_rad_s())
    signatures = _signatures(airframe, omega)
    output = detector.update(4.01, 0.01, (-0.5 * signatures[0, :, 4])[None], signatures)
    assert not output.also_stopped.any() and output.effectiveness[0, 0] == 1.0


def _learnt_detector(airframe, rng, noise_scale=0.01, steps=200, settings=None):
    """A detector that has learnt residual noise of ``noise_scale`` stopped rotors, and its inputs."""
    omega = np.full(airframe.n_rotors, Model(airframe).hover_speed_rad_s())
    signatures = _signatures(airframe, omega)
    _, scale = stopped_rotor_scales(Model(airframe))
    detector = FaultDetector(scale, coaxial_partners(airframe), 1, settings)
    for k in range(steps):
        detector.update(k * 0.01, 0.01, (noise_scale * scale * rng.standard_normal(4))[None], signatures)
    return detector, signatures, scale


def test_after_a_break_no_alarm_until_the_noise_is_learnt_again_then_a_fault_in_that_window_is_found():
    """A fault that came with the gap is no noise: it is judged by the noise learnt before, at once."""
    airframe = load_airframe("hexarotor_f550")
    rng = np.random.default_rng(6)
    detector, signatures, scale = _learnt_detector(airframe, rng)
    detector.relearn()
    outputs = []
    for k in range(200, 300):  # rotor 2 at half thrust from the first sample after the break
        residual = 0.01 * scale * rng.standard_normal(4) - 0.5 * signatures[0, :, 1]
        outputs.append(detector.update(k * 0.01, 0.01, residual[None], signatures))
    relearn_steps = round(detector.settings.relearn_s / 0.01)
    assert all(o.warming_up and not o.alarm[0] for o in outputs[:relearn_steps])
    # The window showed the fault for longer than the persistence: the alarm comes with the window's end.
    alarmed = [k for k, o in enumerate(outputs) if o.alarm[0]]
    assert alarmed and alarmed[0] == relearn_steps
    assert outputs[-1].rotor[0] == 1


def test_relearning_takes_the_noise_after_the_break_when_it_is_larger_and_keeps_the_old_otherwise():
    airframe = load_airframe("hexarotor_f550")
    for after, ratio in ((0.05, 5.0), (0.002, 1.0)):
        detector, signatures, scale = _learnt_detector(airframe, np.random.default_rng(7))
        before = detector.noise_std.copy()
        detector.relearn()
        rng = np.random.default_rng(8)
        for k in range(200, 260):
            detector.update(k * 0.01, 0.01, (after * scale * rng.standard_normal(4))[None], signatures)
        np.testing.assert_allclose(detector.noise_std / before, ratio, rtol=0.35)


def test_an_interruption_restarts_the_persistence_and_an_alarm_outlives_a_break():
    airframe = load_airframe("hexarotor_f550")
    detector, signatures, scale = _learnt_detector(airframe, np.random.default_rng(9))
    stopped = -signatures[0, :, 3][None]
    # Three samples above the threshold, an interruption, three more: never five in a row.
    for k in range(3):
        assert not detector.update(2.0 + 0.01 * k, 0.01, stopped, signatures).alarm[0]
    detector.interrupt()
    for k in range(3):
        assert not detector.update(2.1 + 0.01 * k, 0.01, stopped, signatures).alarm[0]
    for k in range(3, 6):
        output = detector.update(2.1 + 0.01 * k, 0.01, stopped, signatures)
    assert output.alarm[0] and output.rotor[0] == 3
    # In alarm, a break learns nothing from the faulty residual: the alarm stays, no noise is learnt.
    detector.relearn()
    output = detector.update(2.5, 0.01, stopped, signatures)
    assert output.alarm[0] and not output.warming_up


def test_coaxial_pair_is_named_when_the_yaw_residual_cannot_separate_it():
    airframe = load_airframe("x8_octorotor")
    # A yaw channel a hundred times noisier than a rotor's drag torque: rotors 1 and 2 look alike.
    omega = np.full(8, Model(airframe).hover_speed_rad_s())
    signatures = _signatures(airframe, omega)
    _, scale = stopped_rotor_scales(Model(airframe))
    detector = FaultDetector(scale, coaxial_partners(airframe), 1)
    rng = np.random.default_rng(4)
    noise = scale * np.array([0.01, 0.01, 0.01, 1.0])
    for k in range(300):
        residual = noise * rng.standard_normal(4) - (signatures[0, :, 0] if k >= 150 else 0.0)
        output = detector.update(k * 0.01, 0.01, residual[None], signatures)
    assert output.alarm[0] and output.rotor[0] in (0, 1)
    assert output.partner_ambiguous[0]
    reports = rotor_reports(output, 8, coaxial_partners(airframe), 0.5)
    faulty = reports[output.rotor[0]]
    assert faulty.level == "ERROR"
    assert "coaxial partner rotor" in faulty.message and "check both" in faulty.message


def test_reports_are_readable_per_rotor():
    airframe = load_airframe("hexarotor_f550")
    _, outputs = _detector_run(airframe, 4, 0.5, 0.01, np.random.default_rng(5))
    reports = rotor_reports(outputs[-1], 6, coaxial_partners(airframe), 0.5)
    assert [r.name for r in reports] == [f"rotor_{k}" for k in range(1, 7)]
    assert [r.level for r in reports] == ["OK"] * 4 + ["WARN", "OK"]
    assert reports[4].message.startswith("rotor 5 is losing thrust: about 50 % of its thrust left")
    assert reports[0].message == "rotor 1: no fault of its own (rotor 5 is faulty)"
    assert reports[4].values["effectiveness"] == f"{reports[4].effectiveness:.2f}"
    waiting = rotor_reports(None, 6, coaxial_partners(airframe), 0.5)
    assert all(r.level == "OK" and "no verdict yet, waiting for data" in r.message for r in waiting)


def test_detection_settings_refuse_nonsense():
    with pytest.raises(ValueError, match="min_loss must be in"):
        DetectionSettings(min_loss=1.5)
    with pytest.raises(ValueError, match="k_sigma"):
        DetectionSettings(k_sigma=0.0)
    with pytest.raises(ValueError, match="persistence_s"):
        DetectionSettings(persistence_s=float("nan"))


def test_diagnoser_on_a_noise_free_flight_finds_a_stopped_rotor_and_keeps_quiet_before():
    """The whole chain on an exact model (no controller): open-loop hover, rotor 3 stops at 1.5 s."""
    airframe = load_airframe("hexarotor_f550")
    model = Model(airframe)
    truth = Model(airframe, [{"id": "actuator_fault", "motor": 3, "effectiveness": 0.0, "t_fault_s": 1.5}])
    integrator = Integrator(truth, 0.002, ground_height_m=None)
    x = S.make_state(6, position_m=(0, 0, 10), rotor_speed_rad_s=model.hover_speed_rad_s())
    u = np.full((1, 6), model.hover_speed_rad_s())
    diagnoser = RotorDiagnoser(model)
    first_alarm = None
    for k in range(200):
        t = 0.01 * k
        out = diagnoser.update(S.StateBatch.from_flat(t, x, x[:, S.ROTORS_START :]), 0.01)
        if out.detection is not None and out.detection.alarm[0] and first_alarm is None:
            first_alarm = (t, int(out.detection.rotor[0]))
        x = integrator.advance(t, x, u, 5)
    assert first_alarm is not None
    assert 1.5 < first_alarm[0] <= 1.7 and first_alarm[1] == 2
    assert diagnoser.last is not None and diagnoser.last.effectiveness[0, 2] < 0.05
