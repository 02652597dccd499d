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
from services.sim.service import OptionKeys, PaperKeys, SimService, sim_keys

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


def _keys(n: int) -> PaperKeys | OptionKeys:
    schedule = None if n == 2 else OptionsSchedule.default(n)
    keys = sim_keys(NodConfig(), schedule)
    assert isinstance(keys, PaperKeys if n == 2 else OptionKeys)
    return keys


def _events(n: int, keys: PaperKeys | OptionKeys) -> dict[str, Callable[..., m.Message]]:
    """The messages of one key space, by what they say (option 0 the consensus O and target)."""
    if n == 2:
        return {
            "trial": lambda phase: m.TrialEvent(seq=0, t_ns=0, phase=phase, trial=4,
                                                mode="consensus", option="red"),
            "arm": lambda: m.ArmStateMsg(seq=0, t_ns=0, moving=True, target="red"),
            "press": lambda: m.PressMsg(seq=0, t_ns=0, colour="red", trial=4),
        }
    return {
        "trial": lambda phase: m.OptionsTrialEvent(seq=0, t_ns=0, n_options=n, phase=phase,
                                                    trial=4, mode="consensus", option=0),
        "arm": lambda: m.OptionsArmState(seq=0, t_ns=0, n_options=n, moving=True, target=0),
        "press": lambda: m.OptionsPress(seq=0, t_ns=0, n_options=n, option=0, trial=4),
    }


@pytest.mark.parametrize("n", [2, 3])
def test_one_service_drives_the_person_as_the_model_would(n: int) -> None:
    cfg, keys, node = NodConfig(), _keys(n), _Node()
    service = SimService(node, cfg, keys, seed=SEED, rate_hz=30.0, cohort=False)  # type: ignore[arg-type]
    trial_key, arm_key, press_key, layout_key = (
        ("experiment/trial", "actuation/state", "actuation/press", "vision/layout") if n == 2
        else ("options/trial", "options/arm_state", "options/press", "options/layout")
    )
    assert set(node.handlers) == {trial_key, arm_key, press_key, "eyes/cmd"}
    # the reference: the same seed drawn as the service draws it, the model's own values
    seed = int(np.random.default_rng(SEED).integers(2**31))
    reference: Participant[Any] = (
        Participant(cfg.participant, cfg.layout, seed=seed) if n == 2
        else Participant(cfg.participant, cfg.table(n), seed)
    )
    reference.advance(T0 * 1e-9)
    events = _events(n, keys)
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
    if n == 2:
        assert isinstance(layout, m.Layout) and layout.red == m.layout_fields(cfg.layout)["red"]
    else:
        assert isinstance(layout, m.OptionsLayoutMsg)
        assert layout.names == ("red", "blue", "green")
        assert layout.layout() == cfg.table(n)


def test_a_message_for_another_option_count_is_refused() -> None:
    node = _Node()
    keys = _keys(3)
    SimService(node, NodConfig(), keys, seed=SEED, rate_hz=30.0, cohort=False)  # type: ignore[arg-type]
    four = m.OptionsTrialEvent(seq=0, t_ns=0, n_options=4, phase="setup", option=3)
    with pytest.raises(m.MessageError, match="for 4 options but this rig runs 3"):
        node.handlers["options/trial"](four)
