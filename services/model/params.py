"""The one typed configuration of a rig: every SPEC default, in one tree of frozen dataclasses.

Each pure module defines its own parameter class beside its math; this tree only assembles them,
so loading a rig's parameters loads the model and nothing of any service. The TOML file that
overrides it mirrors the fields (e.g. `[decision.bias]`, `[behaviour]`, `[layout.red]`); see
`services.core.config.load_params`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

from services.model.arm_kinematics import SimArmParams
from services.model.behaviour import BehaviourParams
from services.model.debounce import DebounceParams
from services.model.decision import DecisionParams
from services.model.geometry import OptionsLayout, TableLayout
from services.model.participant import ParticipantParams
from services.model.policy import Envelope
from services.model.protocol import ProtocolParams
from services.model.safety import SafetyParams
from services.model.servos import EyesCalibration


@dataclass(frozen=True)
class NodConfig:
    """Every tunable of the system, with SPEC's defaults."""

    layout: TableLayout = field(default_factory=TableLayout)
    decision: DecisionParams = field(default_factory=DecisionParams)
    debounce: DebounceParams = field(default_factory=DebounceParams)  # Algorithm 2 and switches
    behaviour: BehaviourParams = field(default_factory=BehaviourParams)
    sim_arm: SimArmParams = field(default_factory=SimArmParams)
    safety: SafetyParams = field(default_factory=SafetyParams)
    eyes: EyesCalibration = field(default_factory=EyesCalibration)
    protocol: ProtocolParams = field(default_factory=ProtocolParams)
    participant: ParticipantParams = field(default_factory=ParticipantParams)
    policy: Envelope = field(default_factory=Envelope)  # the robot policy's bounds ([policy])

    def summary(self, *sections: str) -> dict[str, Any]:
        """The effective values of some sections (all when none named), for the start-up log."""
        full = dataclasses.asdict(self)
        return {k: v for k, v in full.items() if not sections or k in sections or k == "layout"}

    def table(self, n_options: int) -> OptionsLayout:
        """The table of `n_options` boxes, with the session's commit line.

        The paper's two are `layout` (option 0 red, 1 blue, as z > 0 is red); more are a row
        on its far edge (`OptionsLayout.row`).
        """
        if n_options == 2:
            return OptionsLayout.from_table(self.layout)
        return OptionsLayout(OptionsLayout.row(n_options).boxes, self.layout.commit)
