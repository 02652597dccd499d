"""The one typed configuration of a rig: every SPEC default, overridable from a TOML file.

Sections of the TOML file mirror the fields of `NodConfig` (e.g. `[decision.bias]`,
`[behaviour]`, `[layout.red]`); a key that does not exist is an error at start-up, naming it.
This module only assembles the parameter classes that each pure module defines beside its math.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from services.actuation.arm import SimArmParams
from services.actuation.behaviour import BehaviourParams
from services.core import messages as m
from services.core.config import as_dict, from_mapping, load_toml
from services.core.geometry import Box, CommitLine, TableLayout
from services.decision.model import DecisionParams
from services.experiment.protocol import ProtocolParams
from services.eyes.servos import EyesCalibration
from services.safety.watchdog import SafetyParams
from services.sim.participant import ParticipantParams


@dataclass(frozen=True)
class NodConfig:
    """Every tunable of the system, with SPEC's defaults."""

    layout: TableLayout = field(default_factory=TableLayout)
    decision: DecisionParams = field(default_factory=DecisionParams)
    behaviour: BehaviourParams = field(default_factory=BehaviourParams)
    sim_arm: SimArmParams = field(default_factory=SimArmParams)
    safety: SafetyParams = field(default_factory=SafetyParams)
    eyes: EyesCalibration = field(default_factory=EyesCalibration)
    protocol: ProtocolParams = field(default_factory=ProtocolParams)
    participant: ParticipantParams = field(default_factory=ParticipantParams)

    def summary(self, *sections: str) -> dict[str, Any]:
        """The effective values of some sections (all when none named), for the start-up log."""
        full = as_dict(self)
        return {k: v for k, v in full.items() if not sections or k in sections or k == "layout"}


def add_config_arg(parser: argparse.ArgumentParser) -> None:
    """Add `--params FILE.toml` (SPEC defaults when absent)."""
    parser.add_argument(
        "--params",
        type=Path,
        default=None,
        metavar="FILE.toml",
        help="experiment parameters overriding SPEC defaults (see deploy/params.example.toml)",
    )


def add_service_args(parser: argparse.ArgumentParser) -> None:
    """Every service's common flags: zenoh session, shared clock, `--params`, `-v`."""
    from services.core.clock import add_clock_args
    from services.core.session import add_zenoh_args

    add_zenoh_args(parser)
    add_clock_args(parser)
    add_config_arg(parser)
    parser.add_argument("-v", "--verbose", action="store_true", help="log at debug level")


def load_service_config(path: Path | None) -> NodConfig:
    """The defaults, overridden by a TOML file when given."""
    if path is None:
        return NodConfig()
    return from_mapping(NodConfig, load_toml(path))


def layout_from_msg(msg: m.Layout) -> TableLayout:
    """The table geometry carried by a `vision/layout` message."""
    return TableLayout(red=Box(*msg.red), blue=Box(*msg.blue), commit=CommitLine(y=msg.commit_y))


def layout_fields(layout: TableLayout) -> dict[str, Any]:
    """The fields of a `vision/layout` message for a geometry."""
    r, b = layout.red, layout.blue
    return {
        "red": (r.x1, r.y1, r.x2, r.y2),
        "blue": (b.x1, b.y1, b.x2, b.y2),
        "commit_y": layout.commit.y,
    }
