"""Configuration of the contact observation wrapper: one frozen object holds every option.

:class:`ContactObsConfig` names the feet, the sensor model, the estimator parameters, the
terrain, the rate, the ground-truth source, the observation placement and the metric
keys. :func:`jax_contact.envs.wrapper.wrap_contact` takes it (its keyword arguments, kept for older
callers, only override fields of it). Nothing in it is mutated: override with
``dataclasses.replace`` / ``config.replace(...)``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from flax import struct

from jax_contact.adapter import SOLES
from jax_contact.calibration import Calibration
from jax_contact.defaults import is_number
from jax_contact.envs.feet import FootSpec
from jax_contact.terrain import (
    FlatTerrain,
    FootholdMemory,
    HeightFieldTerrain,
    validate_terrain,
)

# What config.terrain may be (None: the default plane).
TERRAIN_MODELS = (FlatTerrain, HeightFieldTerrain, FootholdMemory)

RATES = ("auto", "substep", "control")
OBSERVE = ("estimate", "truth", "none")
PAIRINGS = ("delayed", "raw")
TRUTH_SOURCES = ("auto", "force_sensors", "found_sensors", "touch_sensors", "contacts", "none")
TERM_NAMES = ("p_dynamics", "p_diff_kinematics", "p_kinematics", "p_takeoff", "p_touchdown")
DEFAULT_OBS_KEYS = ("state",)  # Playground's policy input; an array observation: appended
TRUTH_GAP_MAX = 0.02  # m: truth_gap is a floor tolerance of millimetres, not a swing height


@struct.dataclass
class ContactObsConfig:
    """How the wrapper observes contact. Every field is static (not a pytree leaf).

    Attributes:
      feet: the feet, in the order the features get: None finds them (sphere feet, else
        one foot per body whose geoms touch the floor); else a sequence of names (a geom,
        a body or a site) or :class:`jax_contact.envs.feet.FootSpec` (``envs/feet.py`` for what each
        kind of foot means).
      sensor: a preset name of :data:`jax_contact.envs.sensors.PRESETS` or a
        :class:`~jax_contact.envs.sensors.SensorParams` at the estimator's period.
      params: :class:`jax_contact.EstimatorParams` at the estimator's period; a parameter
        file or shipped preset name (``"go1"``, :func:`jax_contact.load_params`; one made
        at another period runs at the estimator's with a warning,
        :func:`jax_contact.params_file.load_params_for`); None:
        :func:`jax_contact.envs.contact_params.default_estimator_params`.
      calibration: the map applied to the belief's logit before it is observed and scored
        (:mod:`jax_contact.calibration`; the recursion runs on the raw logit):
        ``"auto"`` (default) the map a ``params`` file or preset holds, none otherwise;
        None: no map; or a :class:`jax_contact.Calibration`. The wrapper's
        ``contact_report()`` says which.
      force_rows: world axes of the contact force, for the parameters the wrapper derives
        (refused beside ``params``, which have their own); None: the axes the legs'
        Jacobians span at the home pose, the normal (z) always kept
        (:func:`jax_contact.envs.contact_params.choose_force_rows`).
        The choice is reported by the wrapper's ``contact_report()``.
      terrain: a :mod:`jax_contact.terrain` model; None:
        :func:`jax_contact.envs.contact_params.default_terrain`, or, for a parameter file
        whose provenance names the terrain model it was tuned with (``"memory"``), that
        model over it (:func:`jax_contact.terrain.terrain_for`), as the log commands run it.
      rate: ``"substep"``: an estimator update after every physics step (Brax and
        Playground, :mod:`jax_contact.envs.substeps`); ``"control"``: one per env step (``dt =
        env.dt``); ``"auto"`` (default) is ``"substep"``. The wrapper's ``contact_rate``
        says which runs.
      observe: what the policy sees: ``"estimate"`` the belief; ``"truth"`` the ground
        truth in the same layout (the privileged baseline); ``"none"`` nothing. The
        estimator runs and is scored in all three.
      pairing: ``"delayed"`` (default) or ``"raw"``, as
        :func:`jax_contact.train.evaluate.replay`: the update after step ``k`` evaluates
        the model at the state read at ``k-1`` with the acceleration over ``[k-1, k]`` and
        the torque read at ``k``; ``"raw"`` at ``k``.
      include_logit: also observe the belief's logit (through ``calibration``), clipped to
        ``+-logit_clip``.
      include_terms: also observe the five per-term probabilities.
      obs_keys: the entries of a dict observation that get the features, any set of them
        (Playground's policy input ``"state"``, its critic's ``"privileged_state"``); an
        array observation gets them appended, and any other value than the default is
        refused for it (where the observation size is first read, or at reset).
      info_key: ``state.info`` key of the estimator state (:class:`ContactEstState`); the
        truth goes under ``info_key + "_truth"``, metrics under ``info_key + "/..."``.
        A key the env's own ``info`` already holds is refused at ``reset``, where the
        env's keys are first known.
      truth: ground-truth source, one of :data:`TRUTH_SOURCES`
        (:mod:`jax_contact.envs.contact_truth`).
      truth_threshold: normal force above which a foot is in contact, N.
      truth_gap: (at most :data:`TRUTH_GAP_MAX`) a foot whose sole is less than this
        distance above the floor, or inside it, also counts as in contact, m (default 1
        mm: the micro-bounces of a foot at rest in Playground's soft contact, and a foot
        still inside the soft floor after an impact, :mod:`jax_contact.envs.contact_truth`;
        0: the raw source).
      record_substeps: substep rate only: keep every substep's ``p_contact`` and truth
        (and, with ``truth_gap > 0``, ``truth_raw``: the source without the tolerance),
        (n_substeps, n_legs), and its sensor readings (``reading``, a
        :class:`~jax_contact.envs.sensors.Readings` of (n_substeps, ...) leaves; at reset
        the initial reading), in ``info[info_key + "_substeps"]``.
      include_passive: the estimator's ``h`` includes the joint springs and dampers.
      logit_clip: bound of the observed logit.
      sole: contact point of a flat foot (box, cylinder, mesh), a capsule, or a foot of
        several spheres or capsules of one radius: ``"rolling"`` (default) the lowest part
        of its sole at each step, its centre when it lies flat, the edge, corner or
        sphere it stands on when it rolls; ``"centre"`` the sole's centre at the home
        pose, fixed to the foot (:func:`jax_contact.adapter.contact_points`). A foot of
        one sphere is the same under both.
    """

    feet: tuple | None = struct.field(pytree_node=False, default=None)
    sensor: object = struct.field(pytree_node=False, default="anymal_like")
    params: object = struct.field(pytree_node=False, default=None)
    calibration: object = struct.field(pytree_node=False, default="auto")
    force_rows: tuple[int, ...] | None = struct.field(pytree_node=False, default=None)
    terrain: object = struct.field(pytree_node=False, default=None)
    rate: str = struct.field(pytree_node=False, default="auto")
    observe: str = struct.field(pytree_node=False, default="estimate")
    pairing: str = struct.field(pytree_node=False, default="delayed")
    include_logit: bool = struct.field(pytree_node=False, default=False)
    include_terms: bool = struct.field(pytree_node=False, default=False)
    obs_keys: tuple[str, ...] = struct.field(pytree_node=False, default=DEFAULT_OBS_KEYS)
    info_key: str = struct.field(pytree_node=False, default="contact_est")
    truth: str = struct.field(pytree_node=False, default="auto")
    truth_threshold: float = struct.field(pytree_node=False, default=1.0)
    truth_gap: float = struct.field(pytree_node=False, default=0.001)
    record_substeps: bool = struct.field(pytree_node=False, default=False)
    include_passive: bool = struct.field(pytree_node=False, default=True)
    logit_clip: float = struct.field(pytree_node=False, default=10.0)
    sole: str = struct.field(pytree_node=False, default="rolling")

    @property
    def n_per_foot(self) -> int:
        if self.observe == "none":
            return 0
        return 1 + int(self.include_logit) + len(TERM_NAMES) * int(self.include_terms)


def _one_of(name: str, value, options: Sequence[str]) -> None:
    if value not in options:
        raise ValueError(f"config.{name} must be one of {tuple(options)}, got {value!r}")


def validate_config(cfg: ContactObsConfig) -> None:
    """Raises ValueError naming the first bad field of ``cfg``."""
    if not isinstance(cfg, ContactObsConfig):
        raise ValueError(f"config must be a ContactObsConfig, got {type(cfg).__name__}")
    _one_of("rate", cfg.rate, RATES)
    _one_of("observe", cfg.observe, OBSERVE)
    _one_of("pairing", cfg.pairing, PAIRINGS)
    _one_of("truth", cfg.truth, TRUTH_SOURCES)
    _one_of("sole", cfg.sole, SOLES)
    if cfg.observe == "truth" and cfg.include_terms:
        raise ValueError(
            "config.include_terms has no ground-truth counterpart: observe='truth'"
            " takes p_contact and the logit only"
        )
    if isinstance(cfg.obs_keys, str) or not all(isinstance(k, str) for k in cfg.obs_keys):
        raise ValueError(f"config.obs_keys must be a tuple of str, got {cfg.obs_keys!r}")
    if not cfg.info_key or not isinstance(cfg.info_key, str):
        raise ValueError(f"config.info_key must be a non-empty str, got {cfg.info_key!r}")
    if not cfg.obs_keys and cfg.observe != "none":
        raise ValueError(
            "config.obs_keys is empty: the features would go nowhere (observe='none' runs and"
            " scores the estimator without observing it)"
        )
    for name in ("include_logit", "include_terms", "record_substeps", "include_passive"):
        flag = getattr(cfg, name)
        if not isinstance(flag, bool | np.bool_):  # bool("no") is True, int(2) counts twice
            raise ValueError(f"config.{name} must be True or False, got {flag!r}")
    for name, zero_ok, unit in (
        ("truth_threshold", True, " (N)"),
        ("truth_gap", True, " (m)"),
        ("logit_clip", False, ""),
    ):
        v = getattr(cfg, name)
        if not (is_number(v) and np.isfinite(v) and (v > 0 or (zero_ok and v == 0))):
            low = ">= 0" if zero_ok else "> 0"
            raise ValueError(f"config.{name} must be a number {low}{unit}, got {v!r}")
    if cfg.truth_gap > TRUTH_GAP_MAX:
        raise ValueError(
            f"config.truth_gap must be at most {TRUTH_GAP_MAX} m (a sole this far above the"
            f" floor is in the air), got {cfg.truth_gap!r}: it is a distance in metres"
        )
    if cfg.terrain is not None and not isinstance(cfg.terrain, TERRAIN_MODELS):
        raise ValueError(
            "config.terrain must be None or a jax_contact.terrain model (jc.flat,"
            f" jc.height_field, jc.foothold_memory), got {cfg.terrain!r}"
        )
    if cfg.terrain is not None:
        validate_terrain(cfg.terrain, "config.terrain")
    if not (cfg.calibration in ("auto", None) or isinstance(cfg.calibration, Calibration)):
        raise ValueError(
            "config.calibration must be 'auto', None or a jax_contact.Calibration, got"
            f" {cfg.calibration!r}"
        )
    if cfg.feet is not None:
        if isinstance(cfg.feet, str) or not isinstance(cfg.feet, Sequence) or not cfg.feet:
            raise ValueError(f"config.feet must be a non-empty sequence, got {cfg.feet!r}")
        for i, foot in enumerate(cfg.feet):
            if not isinstance(foot, str | FootSpec):
                raise ValueError(
                    f"config.feet[{i}] must be a name (str) or a FootSpec, got {foot!r}"
                )
    if cfg.force_rows is not None:
        if isinstance(cfg.force_rows, str) or not isinstance(cfg.force_rows, Sequence):
            raise ValueError(
                f"config.force_rows must be a sequence of axes, got {cfg.force_rows!r}"
            )
        rows = tuple(cfg.force_rows)
        if not rows or len(set(rows)) != len(rows) or not set(rows) <= {0, 1, 2}:
            raise ValueError(f"config.force_rows must be distinct axes of 0, 1, 2, got {rows!r}")
        if 2 not in rows:  # the automatic choice always keeps it
            raise ValueError(
                f"config.force_rows {rows!r} leaves out the normal (z, 2): the dynamics term"
                " would not see a foot's load, and its sign test could not run; keep 2"
            )
        if cfg.params is not None:
            raise ValueError(
                "config.force_rows shapes the parameters the wrapper derives; config.params"
                " brings its own (their force_rows): give one of them"
            )
