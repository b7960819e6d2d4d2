"""The model check must find a hidden effect: under each seed one effect of the catalogue
(or none) with a random sensor and magnitude is simulated (tests/modelcheck_cases.py),
the model check runs without being told, and must name exactly that effect and sensor
with the value inside the stated tolerance; clean data must yield no effect. The
extended model must then explain held-out data better than the certificate's."""

from __future__ import annotations

import pytest
from modelcheck_cases import HIDDEN, draw, session, value_ok

from imudiag.certificate import load_default
from imudiag.modelcheck import model_check

SEEDS = range(24)  # every effect of HIDDEN three times


@pytest.mark.parametrize("seed", SEEDS)
def test_hidden_effect_is_named(seed: int) -> None:
    cert = load_default()
    hidden, effects = draw(seed)
    sim = session(cert, seed, effects, turns=hidden.turns)
    report = model_check(sim.samples, cert, seed=seed).report
    named = [(e["name"], e["sensor"]) for e in report["effects"]]
    if hidden.name == "none":
        assert named == [], f"clean data, yet named {report['effects']}"
        for metric in ("residual_rms", "allan_misfit"):
            for triad, g in report["gain"][metric].items():
                assert g is None or g == pytest.approx(1.0), (metric, triad, g)
        return
    assert len(named) == 1 and named[0][0] == hidden.name, (
        f"hid {hidden.name} on {hidden.sensor} ({hidden.value}), named {report['effects']}"
    )
    effect = report["effects"][0]
    assert effect["significance"] >= 5.0
    assert effect["heldout_loglik_gain_nats"] > 0.0
    if effect["sensor"] != hidden.sensor:
        # only where the data cannot tell the sensors apart, and then it must say so
        assert hidden.sensor in effect.get("alternatives", []), (hidden.sensor, effect)
        return
    resolution = report["comparison"]["psd"].get("half0", {}).get("resolution_hz", 0.0)
    ok, msg = value_ok(hidden, effect, resolution)
    assert ok, msg
    # the gain: below 1 on the metric the effect shows in, for its triad
    triad = "gyro" if hidden.sensor.startswith("g") else "accel"
    metric = {
        "periodic_disturbance": "allan_misfit",
        "bias_drift": "allan_misfit",
    }.get(hidden.name, "rotation_rms" if hidden.turns else "residual_rms")
    gain = report["gain"][metric][triad]
    limit = 1.0 if hidden.name == "bias_drift" else 0.95
    assert gain is not None and gain <= limit, (metric, triad, gain, report["gain"])


def test_every_catalogue_effect_is_hidden_by_some_seed() -> None:
    drawn = {draw(seed)[0].name for seed in SEEDS}
    assert drawn == set(HIDDEN)
    sensors = {(h.name, h.sensor) for h in (draw(s)[0] for s in range(200))}
    for name in HIDDEN[1:]:
        triads = {s[0] for n, s in sensors if n == name}
        assert triads == ({"g"} if name == "g_sensitivity" else {"g", "a"}), (name, triads)
