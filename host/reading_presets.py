"""Named readings of the paper's open points (``configs/readings/NAME.yaml``; docs/model.md,
"Two named readings"): ``scored`` (the defaults the readings sweep chose) and
``paper-literal`` (the text read literally). A preset is a set of config overrides applied on
top of a grid preset, before any ``--set``."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from snan_hil.config import loader as configio
from snan_hil.config.loader import ConfigError
from snan_hil.host.config import CONFIG_DIR

READINGS_DIR = CONFIG_DIR / "readings"
#: the preset that gives the model's defaults
DEFAULT_READING = "scored"


@dataclass(frozen=True)
class ReadingPreset:
    """``name``, one-line ``description`` and the dotted-key ``overrides`` it sets."""

    name: str
    description: str
    overrides: dict[str, Any]

    def assignments(self) -> list[str]:
        """The overrides as ``--set`` texts (``key=value``, YAML spelling)."""
        out = []
        for k, v in self.overrides.items():
            text = str(v).lower() if isinstance(v, bool) else str(v)
            out.append(f"{k}={text}")
        return out


def names() -> list[str]:
    """The presets in ``configs/readings/``."""
    return sorted(p.stem for p in READINGS_DIR.glob("*.yaml"))


def load_reading(name: str) -> ReadingPreset:
    """Preset ``name``. Raises :class:`ConfigError` (one line) for an unknown name or a
    malformed file."""
    p = READINGS_DIR / f"{name}.yaml"
    if not p.is_file():
        raise ConfigError(f"no reading preset {name!r} (presets: {', '.join(names())})")
    data = configio.read_yaml(p)
    if not isinstance(data, dict) or not isinstance(data.get("set", {}), dict):
        raise ConfigError(f"reading preset {p}: needs 'description:' and a 'set:' mapping")
    sets = {str(k): v for k, v in (data.get("set") or {}).items()}
    return ReadingPreset(name, str(data.get("description", "")), sets)


def describe(name: str) -> str:
    """``NAME: description (key=value, ...)`` for a report line."""
    r = load_reading(name)
    sets = ", ".join(r.assignments()) or "no overrides"
    return f"{r.name}: {r.description} [{sets}]"
