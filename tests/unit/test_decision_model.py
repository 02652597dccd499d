"""The decision engine: ZOH integration of eq 1 with eq 6, driven by poses (Algorithm 1); the
same engine over N_o options (`OptionsDecision`, `rk4_robot`) against the paper's at N_o = 2.

These tests pin the engine's timing (zero-order hold, timestamps, gaps), so they drive it with
the paper's observer, which reads a pose's direction at once; the default observer's reading
is tested in test_observer_robust.py and, through the engine, in test_decision_oracle.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.analysis.observer_eval import frames, paths
from services.model.bias import BiasParams
from services.model.decision import DecisionModel, DecisionParams, OptionsDecision, rk4_robot
from services.model.dynamics import OptionsParams, PairParams, option_vector, rk4_step, robot_rate
from services.model.geometry import Box, OptionsLayout, TableLayout
from services.model.observer import ObserverParams
from tests.unit.robot_oracle import numpy_rk4_robot

NS = 1_000_000_000
PAPER = DecisionParams(observer=ObserverParams(mode="paper"))


def reach(model: DecisionModel, target, seconds: float, hz: float = 30.0, speed: float = 0.1):
    """Move a one-landmark hand from (0.5, 0.8) toward `target`; return every output."""
    x, y = 0.5, 0.8
    outs = []
    for i in range(int(seconds * hz) + 1):
        dx, dy = target[0] - x, target[1] - y
        dist = math.hypot(dx, dy)
        if dist > 0.05:
            x, y = x + dx / dist * speed / hz, y + dy / dist * speed / hz
        outs.append(model.on_hand(round(i * NS / hz), [(x, y)]))
    return outs


@pytest.mark.parametrize("colour", ["red", "blue"])
def test_unbiased_robot_opposes_the_human(colour):
    model = DecisionModel(PAPER)
    model.reset("dissensus", None)
    outs = reach(model, model.layout.box(colour).corner, 2.0)
    last = outs[-1]
    sign = 1 if colour == "red" else -1
    assert sign * last.z_hat > 0
    assert sign * last.z_r < 0  # γ < 0: the robot takes the other buzzer
    assert last.dissensus and last.b_r == 0.0


@pytest.mark.parametrize("colour", ["red", "blue"])
def test_consensus_mode_follows_option(colour):
    model = DecisionModel(PAPER)
    model.reset("consensus", colour)
    outs = reach(model, model.layout.box(colour).corner, 3.0)
    sign = 1 if colour == "red" else -1
    # The robot first opposes, then the bias pulls it over to O within ~3 s.
    assert any(sign * o.z_r < 0 for o in outs[:15])
    assert sign * outs[-1].z_r > 0 and not outs[-1].dissensus
    assert sign * outs[-1].b_r > model.params.pair.robot.u


def test_zero_order_hold_new_pose_affects_only_later_intervals():
    model = DecisionModel(PAPER)
    model.reset("dissensus", None)
    model.on_hand(0, [(0.5, 0.8)])
    # The pose at t1 moves toward red, but over [0, t1] the held ẑ_h is the first frame's 0:
    # with z_r = b_r = 0 and ẑ_h = 0, ż_r = 0 exactly.
    out1 = model.on_hand(NS // 30, [(0.52, 0.78)])
    assert out1.z_hat > 0 and out1.z_r == 0.0
    # Over [t1, t2] the new ẑ_h acts: the result is RK4 of eq 1 with it held.
    out2 = model.on_hand(2 * NS // 30, [(0.52, 0.78)])
    p = model.params.pair
    z = 0.0
    span = 2 * NS // 30 - NS // 30
    steps = [0.001] * (span // 1_000_000) + [(span % 1_000_000) * 1e-9]
    for h in steps:
        z = rk4_step(lambda v: robot_rate(v, out1.z_hat, 0.0, p), z, h)
    assert out2.z_r < 0
    assert out2.z_r == pytest.approx(z, rel=1e-12)


@pytest.mark.parametrize("bad_t", [0, 5, 10])  # earlier, earlier, repeated
def test_non_advancing_timestamps_do_not_integrate(bad_t):
    model = DecisionModel(PAPER)
    model.reset("consensus", "red")
    model.on_hand(0, [(0.5, 0.8)])
    before = model.on_hand(10, [(0.55, 0.75)])
    before = model.on_hand(10 + NS // 10, [(0.56, 0.74)])
    out = model.on_hand(before.t_ns - 10 + bad_t, [(0.1, 0.1)])  # bad_t ≤ 10 → not after
    assert out.t_ns == before.t_ns
    assert (out.z_r, out.b_r, out.z_hat) == (before.z_r, before.b_r, before.z_hat)
    assert out.observation == before.observation
    # The rejected pose did not move the observer's reference either.
    nxt = model.on_hand(before.t_ns + NS // 30, [(0.56, 0.74)])
    assert nxt.z_hat == before.z_hat and not nxt.observation.moved


def test_max_gap_bound_honoured():
    def primed():
        m = DecisionModel(PAPER)
        m.reset("consensus", "blue")
        m.on_hand(0, [(0.5, 0.8)])
        m.on_hand(NS // 30, [(0.48, 0.78)])
        return m

    long_gap, bounded = primed(), primed()
    t1 = NS // 30
    a = long_gap.on_hand(t1 + 10 * NS, [(0.48, 0.78)])
    b = bounded.on_hand(t1 + NS // 2, [(0.48, 0.78)])
    assert a.t_ns == t1 + 10 * NS  # time moves on even though only 0.5 s was integrated
    assert (a.z_r, a.b_r) == (b.z_r, b.b_r)
    c = primed().on_hand(t1 + 4 * NS // 10, [(0.48, 0.78)])
    assert c.b_r != b.b_r  # a gap under the bound is integrated in full


def test_step_size_does_not_change_the_trajectory_much():
    coarse = DecisionModel(DecisionParams(dt=0.004, observer=PAPER.observer))
    fine = DecisionModel(DecisionParams(dt=0.0005, observer=PAPER.observer))
    for m in (coarse, fine):
        m.reset("consensus", "red")
    a = reach(coarse, coarse.layout.red.corner, 2.0, hz=120)[-1]
    b = reach(fine, fine.layout.red.corner, 2.0, hz=120)[-1]
    assert a.z_r == pytest.approx(b.z_r, abs=1e-3)
    assert a.b_r == pytest.approx(b.b_r, abs=1e-3)


def test_first_pose_sets_time_without_integrating():
    model = DecisionModel(PAPER)
    model.reset("consensus", "red")
    out = model.on_hand(123, [(0.4, 0.4)])
    assert out.t_ns == 123 and model.t_ns == 123
    assert (out.z_r, out.b_r, out.z_hat) == (0.0, 0.0, 0.0)


def test_no_hand_holds_z_hat_and_keeps_integrating():
    model = DecisionModel(PAPER)
    model.reset("dissensus", None)
    model.on_hand(0, [(0.5, 0.8)])
    z_hat = model.on_hand(NS // 30, [(0.52, 0.78)]).z_hat
    out = model.on_hand(NS // 3, None)
    assert not out.observation.detected
    assert out.z_hat == z_hat and out.z_r < 0


def test_reset_clears_state_and_validates():
    model = DecisionModel(PAPER)
    model.reset("consensus", "red")
    reach(model, model.layout.red.corner, 1.0)
    model.reset("consensus", "blue")
    assert (model.z_r, model.b_r, model.z_hat, model.t_ns) == (0.0, 0.0, 0.0, None)
    assert model.mode == "consensus" and model.option == "blue"
    with pytest.raises(ValueError, match="option"):
        model.reset("consensus", None)
    with pytest.raises(ValueError, match="mode"):
        model.reset("agree", "red")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="option"):
        model.reset("dissensus", "green")  # type: ignore[arg-type]


def test_set_layout_mirrors_reading():
    flipped = TableLayout(red=Box(0.14, 0.12, 0.28, 0.26), blue=Box(0.72, 0.12, 0.86, 0.26))
    model = DecisionModel(PAPER)
    model.reset("dissensus", None)
    model.on_hand(0, [(0.5, 0.8)])
    assert model.on_hand(NS // 30, [(0.52, 0.78)]).z_hat > 0  # up-right: red on the right
    model.set_layout(flipped)
    assert model.layout is flipped
    assert model.on_hand(2 * NS // 30, [(0.54, 0.76)]).z_hat < 0  # up-right: now blue


def test_params_validation():
    with pytest.raises(ValueError, match="dt"):
        DecisionParams(dt=0.0)
    with pytest.raises(ValueError, match="max_gap_s"):
        DecisionParams(max_gap_s=-1.0)
    with pytest.raises(ValueError, match="b_max"):
        DecisionParams(bias=BiasParams(b_max=2.0))
    assert DecisionModel(DecisionParams(pair=PairParams())).b_star == pytest.approx(
        2.24 + BiasParams().b_star_margin
    )


@settings(max_examples=40, deadline=None)
@given(
    seq=st.lists(
        st.tuples(
            st.integers(-50_000_000, 300_000_000), st.tuples(st.floats(0, 1), st.floats(0, 1))
        ),
        min_size=2,
        max_size=80,
    ),
    mode=st.sampled_from(["dissensus", "consensus"]),
)
def test_state_stays_finite_and_bounded(seq, mode):
    model = DecisionModel(PAPER)
    model.reset(mode, "blue")
    t = 0
    last_t = None
    for gap, p in seq:
        t += gap
        out = model.on_hand(t, [p])
        if last_t is not None and t <= last_t:
            assert out.t_ns == last_t
        else:
            last_t = t
        assert out.t_ns == last_t
        # |ż_r| ≤ d|z_r| + u + |b_r| keeps |z_r| below (u + b_max)/d from rest.
        bound = (model.params.pair.robot.u + model.params.bias.b_max) / model.params.pair.robot.d
        assert math.isfinite(out.z_r) and abs(out.z_r) <= bound + 1e-9
        assert abs(out.b_r) <= model.params.bias.b_max
        assert out.dissensus == (out.z_r * out.z_hat < 0)


def look_ahead_matches(events, trial) -> None:
    """Drive one model by `on_hand`, another as the service does; every output must agree.

    `events`: (gap ns, event) with event "pose", "no hand", "setup" or "go"; the hand reaches
    up-right from (0.5, 0.85) pose by pose.
    """
    plain, ahead = DecisionModel(), DecisionModel()
    for model in (plain, ahead):
        model.reset(*trial)
    t, k = 0, 0
    for gap, what in events:
        t += gap
        if what in ("setup", "go"):
            assert plain.on_trial(what, *trial) == ahead.on_trial(what, *trial)
            continue
        k += 1
        pts = [(0.5 + 0.01 * k, 0.85 - 0.012 * k)] * 21 if what == "pose" else None
        expected = plain.on_hand(t, pts)
        if ahead.advance(t):
            z_r_first = ahead.z_r
            got = ahead.read(pts)
            assert z_r_first == got.z_r
        else:
            got = ahead.on_hand(t, pts)
        ahead.look_ahead()
        assert got == expected


@pytest.mark.parametrize("trial", [("dissensus", None), ("consensus", "red")])
def test_look_ahead_changes_no_value_when_poses_come_late_early_or_stale(trial):
    # The decision service publishes z_r after `advance`, reads the pose, then `look_ahead`s
    # the next interval: every output must be bit for bit what `on_hand` alone gives.
    camera = [(33_333_333, "pose")] * 12
    irregular = [(50_000_000, "pose"), (20_000_000, "pose"), (33_333_333, "pose"),
                 (0, "pose"), (-5, "pose"), (700_000_000, "pose"), (33_000_000, "no hand"),
                 (34_000_001, "pose"), (1, "pose"), (10_000_000, "go"), (33_333_333, "pose")]
    look_ahead_matches(camera + irregular + camera, trial)


@settings(max_examples=40, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.one_of(  # the gap to the last pose (ns): camera periods, late, early, stale
                st.sampled_from([33_333_333, 8_333_333, 41_000_000, 0, -1, 700_000_000]),
                st.integers(-2_000_000, 80_000_000),
            ),
            st.sampled_from(["pose", "pose", "pose", "no hand", "setup", "go"]),
        ),
        min_size=1,
        max_size=60,
    ),
    st.sampled_from([("dissensus", None), ("consensus", "red"), ("consensus", "blue")]),
)
def test_look_ahead_changes_no_value(events, trial):
    look_ahead_matches(events, trial)


def test_read_before_advance_says_what_to_do():
    with pytest.raises(RuntimeError, match="advance"):
        DecisionModel().read([(0.5, 0.8)])


# -- Over N_o options: the general engine, and the paper's kernel at N_o = 2 ---------------------


def pose_stream(seed: int) -> list[tuple[int, list[tuple[float, float]]]]:
    """Jittered reaches (one a change of mind) at 30 Hz with the camera's uneven frame times,
    one after another as the trials of a session."""
    rng = np.random.default_rng(seed)
    out: list[tuple[int, list[tuple[float, float]]]] = []
    t_ns = NS
    for path in paths()[:4]:
        for _, landmarks, _ in frames(path, 30.0, 2.0, rng):
            t_ns += int(rng.integers(25_000_000, 42_000_000))
            out.append((t_ns, landmarks))
    return out


@pytest.mark.parametrize(("mode", "option"), [("dissensus", None), ("consensus", "red"),
                                              ("consensus", "blue")])
def test_two_options_the_general_engine_follows_the_papers(mode: str, option: str | None) -> None:
    """On the same pose stream, `OptionsDecision` over the paper's two boxes is `DecisionModel`:
    the same ẑ_h (the observers agree exactly), and z_r and b_r to 1e-12 at every pose, eq 6
    included (the two RK4s, the gap bound and the step splitting)."""
    table = TableLayout()
    paper = DecisionModel(DecisionParams(), table)
    general = OptionsDecision(OptionsLayout.from_table(table), DecisionParams())
    index = {None: None, "red": 0, "blue": 1}[option]
    paper.on_trial("go", mode, option)  # type: ignore[arg-type]
    general.on_trial("go", mode, index)  # type: ignore[arg-type]
    moving = 0
    poses = pose_stream(7)
    for t_ns, landmarks in poses:
        want, got = paper.on_hand(t_ns, landmarks), general.on_hand(t_ns, landmarks)
        assert got.t_ns == want.t_ns
        assert got.z_hat.tolist() == [want.z_hat, -want.z_hat]
        assert got.z_r[0] == pytest.approx(want.z_r, abs=1e-12)
        assert got.z_r[1] == -got.z_r[0]
        assert got.b_r[0] == pytest.approx(want.b_r, abs=1e-12)
        moving += abs(want.z_r) > 0.02
    assert moving > len(poses) // 3  # the stream moved the robot: the comparison was not of zeros
    if mode == "consensus":
        assert abs(paper.b_r) > 1.0  # and the controller ran


# Opinions away from underflow: the freeze is a discrete test, and the kernel's z_r · ẑ_h < 0
# reads a product that underflows to −0.0 (|z_r ẑ_h| < 1e-323) as agreement, where the general
# form's argmax test sees the disagreement: a difference of no physical meaning.
def readable(top: float) -> st.SearchStrategy[float]:
    return st.one_of(st.just(0.0), st.floats(1e-3, top), st.floats(-top, -1e-3))


@settings(max_examples=300, deadline=None)
@given(
    z_r=readable(3.0),
    b_r=st.floats(-5.5, 5.5),
    z_hat=readable(8.0),
    option=st.sampled_from([None, "red", "blue"]),
    n=st.integers(1, 60),
    h=st.sampled_from([1e-3, 3.33333e-4, 2.5e-3]),
)
def test_two_options_the_general_rk4_is_the_papers_kernel(z_r, b_r, z_hat, option, n, h):
    """The kernel-vs-general property at N_o = 2: `rk4_robot` on (x, −x) with s = b_r · sgn(O)
    and ẑ_h = (m, −m) gives `DecisionModel._run`'s (z_r, b_r) to 1e-12, eq 6's freeze, clamp
    and sign of O included (b_r ≡ 0 in dissensus, as the engines keep it)."""
    model = DecisionModel(DecisionParams())
    model.reset("consensus" if option else "dissensus", option)
    b_r = b_r if option else 0.0
    sign_o = -1.0 if option == "blue" else 1.0
    want_z, want_b = model._run(z_r, b_r, z_hat, n, h)
    got_z, got_s = rk4_robot(
        [z_r, -z_r], b_r * sign_o, [z_hat, -z_hat], [h] * n, OptionsParams(n_options=2),
        {None: None, "red": 0, "blue": 1}[option], model.params.bias,
    )
    assert abs(got_z[0] - want_z) <= 1e-12
    assert got_z[1] == -got_z[0]
    assert abs(got_s * sign_o - want_b) <= 1e-12


@settings(max_examples=60, deadline=None)
@given(
    st.integers(2, 5), st.lists(st.floats(-2.0, 2.0), min_size=10, max_size=10),
    st.floats(-5.5, 5.5), st.sampled_from([None, 0, 1]), st.integers(0, 4), st.floats(0.05, 3.0),
    st.sampled_from([0.0, 0.3]), st.sampled_from([0.0, -0.7]),
)
def test_the_float_rk4_is_the_numpy_reference(
    n: int, raw: list[float], s: float, option: int | None, h: int, m: float, beta: float,
    delta: float,
) -> None:
    """`rk4_robot` on plain floats against the NumPy reference built on `general_rates`
    (tests/unit/robot_oracle.py), for any N_o, β and δ: 1e-12, and on the subspace exactly."""
    z_r = np.array(raw[:n]) - np.mean(raw[:n])
    z_hat = m * option_vector(h % n, n)
    p, bias = OptionsParams(n_options=n, beta=beta, delta=delta), BiasParams()
    steps = [0.001] * 40 + [0.0004]
    want_z, want_s = numpy_rk4_robot(z_r, s, z_hat, steps, p, option, bias)
    got_z, got_s = rk4_robot(z_r, s, z_hat, steps, p, option, bias)
    assert np.max(np.abs(got_z - want_z)) < 1e-12
    assert abs(got_s - want_s) < 1e-12
    assert got_z.sum() == pytest.approx(0.0, abs=1e-15)


def test_bias_params_reach_the_general_rk4() -> None:
    """A zero-gain controller leaves s at zero: the parameters passed in are the ones used."""
    p = OptionsParams(n_options=3)
    z_hat = 6.0 * option_vector(0, 3)
    _, s = rk4_robot(np.zeros(3), 0.0, z_hat, [0.001] * 500, p, 1, BiasParams(sigma=0.0))
    assert s == 0.0
    _, s = rk4_robot(np.zeros(3), 0.0, z_hat, [0.001] * 500, p, 1)
    assert s > 1.0


def test_the_general_engine_refuses_what_the_papers_refuses() -> None:
    engine = OptionsDecision(OptionsLayout.row(3))
    with pytest.raises(ValueError, match="mode"):
        engine.reset("both", None)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="option"):
        engine.reset("consensus", 3)
    with pytest.raises(ValueError, match="consensus option O"):
        engine.reset("consensus", None)
    with pytest.raises(RuntimeError, match="advance"):
        engine.read(None)
    assert engine.on_trial("go", "dissensus", 2) and engine.option is None
    assert not engine.on_trial("end", "consensus", 2)
