"""`nod sim`'s one service at two and three options: the key space is the only difference.

A fake node (no zenoh) records what the service subscribes to and publishes, building every
message with the contract's class for its key, so a field the schema does not have fails here.
The person the service drives is held to a `Participant` driven directly with the model's
values: the service adds nothing but the conversion of its key space.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from services.core import messages as m
from services.core.contract import check_publisher
from services.model.gaze import GazeCommand
from services.model.params import NodConfig
from services.model.participant import Participant
from services.model.schedule import OptionsSchedule
from services.sim.service import OptionsSeam, PaperSeam, SimService, sim_seam

T0 = 1_000_000_000
SEED = 3


class _Clock:
    def __init__(self) -> None:
        self.t_ns = T0

    def now_ns(self) -> int:
        return self.t_ns


class _Publisher:
    def __init__(self, node: _Node, topic: str) -> None:
        self.cls = check_publisher(topic, "sim").message
        self.sent: list[m.Message] = []
        self.seq = 0
        node.sent[topic] = self.sent

    def put(self, t_ns: int | None = None, **fields: Any) -> m.Message:
        msg = self.cls(seq=self.seq, t_ns=T0 if t_ns is None else t_ns, **fields)
        self.seq += 1
        self.sent.append(msg)
        return msg


class _Node:
    """What SimService uses of a Node: a clock, publishers, subscriptions and ticks."""

    def __init__(self) -> None:
        self.clock = _Clock()
        self.sent: dict[str, list[m.Message]] = {}
        self.handlers: dict[str, Callable[[Any], None]] = {}
        self.ticks: list[tuple[float, Callable[[int], None]]] = []

    def publisher(self, topic: str) -> _Publisher:
        return _Publisher(self, topic)

    def subscribe(self, topic: str, handler: Callable[[Any], None]) -> None:
        self.handlers[topic] = handler

    def every(self, period_s: float, fn: Callable[[int], None]) -> None:
        self.ticks.append((period_s, fn))


def _seam(n: int) -> PaperSeam | OptionsSeam:
    schedule = None if n == 2 else OptionsSchedule.default(n)
    seam = sim_seam(NodConfig(), schedule)
    assert isinstance(seam, PaperSeam if n == 2 else OptionsSeam)
    return seam


def _events(n: int) -> dict[str, Callable[..., m.Message]]:
    """The messages of one option set, by what they say (option 0 the consensus O and target)."""
    names = OptionsSchedule.default(n).names
    return {
        "trial": lambda phase: m.TrialEvent(seq=0, t_ns=0, phase=phase, trial=4,
                                            mode="consensus", option="red", options=names),
        "arm": lambda: m.ArmStateMsg(seq=0, t_ns=0, moving=True, target="red"),
        "press": lambda: m.PressMsg(seq=0, t_ns=0, option="red", trial=4),
    }


@pytest.mark.parametrize("n", [2, 3])
def test_one_service_drives_the_person_as_the_model_would(n: int) -> None:
    cfg, seam, node = NodConfig(), _seam(n), _Node()
    service = SimService(node, cfg, seam, seed=SEED, rate_hz=30.0, cohort=False)  # type: ignore[arg-type]
    # one key space whatever the number of options
    trial_key, arm_key, press_key, layout_key = (
        "experiment/trial", "actuation/state", "actuation/press", "vision/layout"
    )
    assert set(node.handlers) == {trial_key, arm_key, press_key, "eyes/cmd"}
    # the reference: the same seed drawn as the service draws it, the model's own values
    seed = int(np.random.default_rng(SEED).integers(2**31))
    reference: Participant[Any] = (
        Participant(cfg.participant, cfg.layout, seed=seed) if n == 2
        else Participant(cfg.participant, cfg.table(n), seed)
    )
    reference.advance(T0 * 1e-9)
    events = _events(n)
    gaze = m.GazeMsg(seq=0, t_ns=0, yaw=0.3, pitch=-0.1)
    hand_seen: list[tuple[tuple[float, float], ...]] = []

    def at(t_ns: int) -> None:
        node.clock.t_ns = t_ns
        reference.advance(t_ns * 1e-9)

    at(T0 + 10_000_000)
    node.handlers[trial_key](events["trial"]("setup"))
    reference.new_trial("red" if n == 2 else 0)  # type: ignore[arg-type]
    node.handlers["eyes/cmd"](gaze)
    reference.see_gaze(0.3 if n == 2 else GazeCommand(0.3, -0.1))
    at(T0 + 500_000_000)
    node.handlers[trial_key](events["trial"]("go"))
    reference.go(reference.t)
    frame = next(fn for period, fn in node.ticks if period < 1.0)
    for i in range(1, 240):  # eight seconds at 30 Hz: the arm heads for option 0 after one
        t_ns = T0 + 500_000_000 + i * 33_333_333
        if i == 30:
            node.clock.t_ns = t_ns
            node.handlers[arm_key](events["arm"]())
            reference.see_robot(t_ns * 1e-9, 1 if n == 2 else 0)
        frame(t_ns)
        reference.advance(t_ns * 1e-9)
        hand_seen.append(tuple((float(x), float(y)) for x, y in reference.landmarks()))
    node.handlers[press_key](events["press"]())
    assert service.robot == ("red" if n == 2 else 0)
    node.handlers[trial_key](events["trial"]("end"))
    reference.trial_ended("red" if n == 2 else 0)  # type: ignore[arg-type]
    hands = node.sent["vision/hand"]
    assert [h.landmarks for h in hands] == hand_seen  # type: ignore[attr-defined]
    assert tuple(service.person.pos) == tuple(reference.pos)
    assert service.person.trust == reference.trust
    assert service.person.pressed == reference.pressed is not None
    layout_tick = next(fn for period, fn in node.ticks if period == 1.0)
    layout_tick(T0)
    (layout,) = node.sent[layout_key]
    assert isinstance(layout, m.Layout)
    assert layout.options == OptionsSchedule.default(n).names
    if n == 2:
        assert layout.paper_table() == cfg.layout
    else:
        assert layout.table() == cfg.table(n)


def test_a_message_for_another_option_set_is_refused() -> None:
    node = _Node()
    SimService(node, NodConfig(), _seam(3), seed=SEED, rate_hz=30.0, cohort=False)  # type: ignore[arg-type]
    four = m.TrialEvent(seq=0, t_ns=0, phase="setup", option="yellow",
                        options=("red", "blue", "green", "yellow"))
    with pytest.raises(m.MessageError, match="for options red,blue,green,yellow but this rig "
                                             "runs red,blue,green"):
        node.handlers["experiment/trial"](four)
    with pytest.raises(m.MessageError, match="option 'yellow' is none of this rig's"):
        node.handlers["actuation/press"](m.PressMsg(seq=0, t_ns=0, option="yellow", trial=1))
