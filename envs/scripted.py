"""Open-loop gaits in place for quadrupeds with joint position actuators.

A scripted policy is a sequence of joint position offsets from the standing pose, the
same for every step of a rollout whatever the robot does: no balance, no feedback. Used
where no trained policy is at hand, to measure the wrapped estimator on contact patterns
like a gait's (the rates scenes of :mod:`jax_contact.train.rates` and the Playground
benchmark ``benchmarks/wrapper_accuracy.py``).

Each leg swings for ``swing`` of a cycle of ``freq`` Hz with the profile ``sin^2(pi s)``
(``s`` in [0, 1) the swing's progress; zero velocity at lift-off and touch-down, as in a
gait), the hip pitch raised by ``hip`` and the knee bent by ``knee`` radians at the apex:

- ``walk``: a lateral-sequence walk, one leg in the air at a time, 0.2 of a 1 Hz cycle,
  hip 0.3 rad, knee 0.6 rad;
- ``trot``: diagonal pairs in turn, 0.4 of a 2 Hz cycle each, hip 0.4 rad, knee 0.7 rad.

These settings were chosen on Playground's Go1 on seed 0 (docs/training.md, "Why the
wrapped Go1 scored 0.90"): the walk puts feet down slowly, as a walking robot does; the
trot drags feet in stance (35 % of its contact steps slide faster than 0.2 m/s), as a
trained policy penalised for foot slip would not.
"""

from __future__ import annotations

import numpy as np

# (cycle frequency Hz, swing share of the cycle, hip pitch rad, knee rad) at the apex.
SETTINGS = {"walk": (1.0, 0.2, 0.3, 0.6), "trot": (2.0, 0.4, 0.4, 0.7)}
POLICIES = tuple(SETTINGS)
# Phase of each leg's swing in the cycle, in the actuator order (Go1: FR FL RR RL; Spot:
# FL FR HL HR): the walk's sequence is hind right, front right, hind left, front left.
PHASES = {
    "walk": {"Go1": (0.0, 0.5, 0.75, 0.25), "Spot": (0.5, 0.0, 0.25, 0.75)},
    "trot": {"Go1": (0.0, 0.5, 0.5, 0.0), "Spot": (0.0, 0.5, 0.5, 0.0)},
}


def swing_profile(t: np.ndarray, freq, phase, swing: float) -> np.ndarray:
    """Swing profile in [0, 1]: ``sin^2`` over the swing share of each cycle, 0 in stance.

    Args:
      t: times, s, broadcast against ``freq`` and ``phase`` (e.g. (T, 1) against (E,)).
      freq: cycle frequency, Hz.
      phase: phase of the swing's start in the cycle, in cycles.
      swing: share of the cycle spent swinging, in (0, 1].
    """
    ph = (freq * t + phase) % 1.0
    return np.where(ph < swing, np.sin(np.pi * ph / swing) ** 2, 0.0)


def in_place_offsets(
    policy: str, robot: str, t: np.ndarray, rate: np.ndarray, phase0: np.ndarray
) -> np.ndarray:
    """Joint position offsets of a scripted gait in place, rad.

    Args:
      policy: one of :data:`POLICIES`.
      robot: ``"Go1"`` or ``"Spot"`` (the leg order of :data:`PHASES`; 3 actuators per
        leg, hip abduction, hip pitch, knee, legs in that order).
      t: (T, 1) times, s.
      rate: (E,) each rollout's frequency as a multiple of the policy's.
      phase0: (E,) each rollout's phase offset, cycles.

    Returns:
      (T, E, 12) offsets to add to the standing pose's position targets.
    """
    if policy not in SETTINGS:
        raise ValueError(f"policy must be one of {POLICIES}, got {policy!r}")
    if robot not in PHASES[policy]:
        raise ValueError(f"policy {policy!r} is for {tuple(PHASES[policy])}, not {robot!r}")
    freq, swing, hip, knee = SETTINGS[policy]
    rate, phase0 = np.asarray(rate, float), np.asarray(phase0, float)
    out = np.zeros((t.shape[0], rate.shape[0], 12))
    for leg, off in enumerate(PHASES[policy][robot]):
        s = swing_profile(t, freq * rate, phase0 + off, swing)
        out[:, :, 3 * leg + 1] += hip * s
        out[:, :, 3 * leg + 2] -= knee * s
    return out
