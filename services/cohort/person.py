"""The default simulated person: SPEC's participant model with the traits fitted to the paper.

`nod cohort`, `nod analyze power`, `nod calibrate-cohort` and `nod sim` (so `nod run --sim`)
draw their participants from `paper/paper_fig8a.toml` (the traits `nod calibrate-cohort` fitted
to the paper's Fig 8a and 8b; the file says how) unless a `--params` file says otherwise: its
`[participant]` keys replace the fitted ones key by key, and its other tables apply as
everywhere. The file ships inside the package, so an installed wheel finds it.
"""

from __future__ import annotations

import tomllib
from importlib import resources
from pathlib import Path
from typing import Any

from services.core.config import ConfigError, from_mapping, load_toml
from services.model.params import NodConfig

PAPER = resources.files("services.cohort") / "paper"
FITTED_TRAITS = PAPER / "paper_fig8a.toml"  # the default person (written by calibrate-cohort)
FIG8A = PAPER / "paper_fig8a.json"  # the paper's per-trial shares: the calibration's target
FIG8B = PAPER / "paper_fig8b.json"  # the paper's control → experiment flows


def fitted_traits() -> dict[str, Any]:
    """The shipped fitted `[participant]` table."""
    try:
        return dict(tomllib.loads(FITTED_TRAITS.read_text())["participant"])
    except (OSError, KeyError, tomllib.TOMLDecodeError) as exc:  # a broken install
        raise ConfigError(f"the shipped fitted traits {FITTED_TRAITS} cannot be read: {exc}"
                          ) from None


def load_cohort_params(path: str | Path | None) -> NodConfig:
    """SPEC defaults ← the fitted person's traits ← the `--params` file at `path` (if any)."""
    return cohort_params(load_toml(path) if path is not None else {}, str(path))


def cohort_params(data: dict[str, Any], where: str) -> NodConfig:
    """SPEC defaults ← the fitted person's traits ← a `--params` file's tables (from `where`)."""
    own = data.get("participant", {})
    if not isinstance(own, dict):
        raise ConfigError(f"{where}: participant: expected a table, got {type(own).__name__}")
    person = {**fitted_traits(), **own}
    return from_mapping(NodConfig, {**data, "participant": person})
