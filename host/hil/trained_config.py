"""Check the model a launch will run against the training config stored in the weights file.

``snan-hil train`` stores the SNAN config it trained with (``config`` in the ``.npz``, the
HIL config's :meth:`~snan_hil.host.hil.config.HilConfig.train_config`). ``run`` and ``compare``
build the same training config from their own ``--config``/``--set`` and compare the two key by
key (:func:`snan_hil.config.loader.differences`; ``name`` is a label and is not compared):

* a difference in a key that acts during a launch (grid, input, neuron, the fixed synapses,
  astrocytes, decision rule; the step limit) means the weights would run in a network they were
  not trained in: :func:`check_trained_config` refuses with one line listing the differences,
  unless the caller accepts them (``--accept-config-diff``), when they are reported and kept
  in the results;
* a difference only in :data:`TRAINING_ONLY` keys (STDP: off in every launch; the initial
  weight draw: launches take the weights from the file) does not change a launch; it is
  reported as a note.

Why refuse by default: a lab run on the board takes minutes to hours and its output records
the launch config as the experiment's; a forgotten ``--config`` or ``--set`` would otherwise
give results of another model without a word. A deliberate change (e.g. another astrocyte
setting on fixed weights) is one flag away and is recorded in the output.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from snan_hil.config import loader as configio
from snan_hil.config.loader import ConfigError
from snan_hil.common.errors import UserError
from snan_hil.host.config import from_stored
from snan_hil.host.hil.config import HilConfig

#: Keys (prefixes) that act only while training: STDP is off in every launch
#: (``HilConfig.launch_config``) and the initial weights are drawn only when no weights are
#: given (``host.agent.run_trial``); tested in tests/hil/test_hil_trained_config.py.
TRAINING_ONLY = ("stdp.", "vteam.", "synapse.w_mean", "synapse.w_std", "synapse.w_lo",
                 "synapse.w_hi", "synapse.init")
IGNORED = ("name",)
ACCEPT_FLAG = "--accept-config-diff"
SHOWN = 6                    #: differences spelled out in the one-line message


class TrainedConfigMismatch(UserError):
    """The launch model differs from the weights' training config in keys a launch uses."""


@dataclass
class TrainedConfigCheck:
    """Outcome of :func:`check_trained_config` (``stored`` False: the file holds no config)."""

    stored: bool
    launch: list[tuple[str, Any, Any]] = field(default_factory=list)
    training_only: list[tuple[str, Any, Any]] = field(default_factory=list)
    accepted: bool = False

    def to_dict(self) -> dict[str, Any]:
        def rows(diffs: list[tuple[str, Any, Any]]) -> list[dict[str, Any]]:
            return [{"key": k, "trained": _plain(a), "launch": _plain(b)} for k, a, b in diffs]
        return {"stored": self.stored, "launch_differences": rows(self.launch),
                "training_only_differences": rows(self.training_only),
                "accepted": self.accepted}

    def notes(self, path: str) -> list[str]:
        """One line each for the differences a caller should show (empty when none)."""
        out = []
        if not self.stored:
            out.append(f"note: {path} holds no training config; the launch model is not checked")
        if self.launch:
            out.append(f"warning: launching {path} with a model it was not trained in "
                       f"({ACCEPT_FLAG}): {describe(self.launch)}")
        if self.training_only:
            out.append(f"note: {path} was trained with other training-only settings (not used "
                       f"in launches): {describe(self.training_only)}")
        return out


def _plain(v: Any) -> Any:
    return None if v is configio.MISSING else v


def _fmt(v: Any) -> str:
    return "(absent)" if v is configio.MISSING else f"{v!r}" if isinstance(v, str) else f"{v}"


def describe(diffs: list[tuple[str, Any, Any]], shown: int = SHOWN) -> str:
    """``"astro.a 6.0 (trained) vs 3.0 (now), ..."`` with at most ``shown`` keys."""
    parts = [f"{k} {_fmt(a)} (trained) vs {_fmt(b)} (now)" for k, a, b in diffs[:shown]]
    if len(diffs) > shown:
        parts.append(f"and {len(diffs) - shown} more")
    return ", ".join(parts)


def _training_only(key: str) -> bool:
    return any(key == p or (p.endswith(".") and key.startswith(p)) for p in TRAINING_ONLY)


def check_trained_config(meta: dict, hil: HilConfig, path: str, *, accept: bool = False
                         ) -> TrainedConfigCheck:
    """Compare ``meta["config"]`` (from :func:`~snan_hil.calibration.weights_io.load_weight_set`)
    with ``hil.train_config()``.

    Raises :class:`TrainedConfigMismatch` (one line naming every differing key, at most
    :data:`SHOWN` spelled out, and the flag) when a key a launch uses differs and ``accept`` is
    False; :class:`~snan_hil.config.loader.ConfigError` if the stored config is not a readable
    SNAN config. Returns the differences otherwise."""
    stored = meta.get("config")
    if stored is None:
        return TrainedConfigCheck(stored=False)
    if not isinstance(stored, dict):
        raise ConfigError(f"{path}: the stored training config is not a mapping; retrain with "
                          "'snan-hil train' or pass a .npy without a config")
    trained = from_stored(stored, where=f"{path}: stored training config").to_dict()
    now = hil.train_config().to_dict()
    diffs = [d for d in configio.differences(trained, now) if d[0] not in IGNORED]
    check = TrainedConfigCheck(stored=True,
                               launch=[d for d in diffs if not _training_only(d[0])],
                               training_only=[d for d in diffs if _training_only(d[0])],
                               accepted=accept)
    if check.launch and not accept:
        raise TrainedConfigMismatch(
            f"{path} was trained with another model: {describe(check.launch)}; give the "
            f"--config/--set of 'snan-hil train', or {ACCEPT_FLAG} to launch it anyway")
    return check
