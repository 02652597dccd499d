"""The closed loop's speed-ups change no value: each fast path against the plain code, bit for bit.

A cohort's outcomes must stay the same for the same seeds, so every shortcut of the hot loop
(the decision model's RK4 written out and stopped at a fixed point, the participant's RK4
written out, the arm at rest, the loop's press pre-test and landmark mean) is checked here
against the straightforward computation it replaces. Floats are compared by `float.hex`, so a
zero's sign counts too.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.cohort.person import load_cohort_params
from services.model import closed_loop
from services.model.arm import SimArm
from services.model.arm_kinematics import PointArm
from services.model.behaviour import ArmCommand
from services.model.bias import bias_active, bias_rate
from services.model.closed_loop import centre, run_offline_session, view_of
from services.model.compiled import hypot_kernel, py_hypot, rk4_pair, view_kernel
from services.model.decision import DecisionModel, DecisionParams, OptionsDecision
from services.model.dynamics import opinion_rate, rk4_step
from services.model.geometry import TableLayout
from services.model.params import NodConfig
from services.model.participant import Participant, ParticipantParams
from services.model.schedule import OptionsSchedule

LAYOUT = TableLayout()
finite = st.floats(-3.0, 3.0, allow_nan=False)


def bits(*values: float) -> list[str]:
    return [float(v).hex() for v in values]


def plain_run(
    model: DecisionModel, z_r: float, b_r: float, z_hat: float, n: int, h: float
) -> list[tuple[float, float]]:
    """n RK4 steps of eq 1 and eq 6 through `opinion_rate` and `bias_rate`, every step taken."""
    params = model.params
    r = params.pair.robot
    gamma_a = r.gamma * params.pair.a_rh
    consensus = model.mode == "consensus"
    sigma, beta, b_star = model._sigma, model._beta, model.b_star
    b_max = params.bias.b_max
    hh = 0.5 * h

    def rate(z: float, b: float) -> float:
        return opinion_rate(z, z_hat, b, r.d, r.u, r.alpha, gamma_a, math.tanh)

    def b_rate(b: float, z: float) -> float:
        return bias_rate(b, z, z_hat, sigma, beta, b_star)

    path = []
    for _ in range(n):
        k1z = rate(z_r, b_r)
        if consensus and bias_active(z_r, z_hat):
            k1b = b_rate(b_r, z_r)
            z2, b2 = z_r + hh * k1z, b_r + hh * k1b
            k2z, k2b = rate(z2, b2), b_rate(b2, z2)
            z3, b3 = z_r + hh * k2z, b_r + hh * k2b
            k3z, k3b = rate(z3, b3), b_rate(b3, z3)
            z4, b4 = z_r + h * k3z, b_r + h * k3b
            k4z, k4b = rate(z4, b4), b_rate(b4, z4)
            b_r += (h / 6.0) * (k1b + 2.0 * k2b + 2.0 * k3b + k4b)
            b_r = max(-b_max, min(b_max, b_r))
        else:
            k2z = rate(z_r + hh * k1z, b_r)
            k3z = rate(z_r + hh * k2z, b_r)
            k4z = rate(z_r + h * k3z, b_r)
        z_r += (h / 6.0) * (k1z + 2.0 * k2z + 2.0 * k3z + k4z)
        path.append((z_r, b_r))
    return path


@settings(max_examples=300, deadline=None)
@given(
    z_r=finite,
    b_r=st.floats(-2.0, 2.0),
    z_hat=st.one_of(finite, st.just(0.0), st.just(-0.0)),
    option=st.sampled_from([None, "red", "blue"]),
    n=st.integers(1, 60),
    h=st.sampled_from([1e-3, 3.33333e-4, 2.5e-3]),
)
def test_decision_steps_are_the_rate_functions_bit_for_bit(z_r, b_r, z_hat, option, n, h):
    model = DecisionModel(DecisionParams(), LAYOUT)
    model.reset("consensus" if option else "dissensus", option)
    path: list[tuple[float, float]] = []
    end = model._run(z_r, b_r, z_hat, n, h, path)
    want = plain_run(model, z_r, b_r, z_hat, n, h)
    assert [bits(*s) for s in path] == [bits(*s) for s in want]
    assert bits(*end) == bits(*want[-1])


@settings(max_examples=300, deadline=None)
@given(
    z_r=finite,
    b_r=st.one_of(st.floats(-7.0, 7.0), st.just(0.0), st.just(-0.0)),
    z_hat=st.one_of(finite, st.just(0.0), st.just(-0.0)),
    option=st.sampled_from([None, "red", "blue"]),
    n=st.integers(1, 60),
    h=st.sampled_from([1e-3, 3.33333e-4, 2.5e-3, 1e-9]),
    u=st.sampled_from([None, 0.5, 3.0]),
)
def test_the_compiled_decision_steps_are_pythons_bit_for_bit(z_r, b_r, z_hat, option, n, h, u):
    """`services.model.compiled` (Numba, no fastmath) takes `_run`'s steps to the same bits,
    dissensus and consensus (the bias clamped at b_max included), as the engine calls it."""
    params = DecisionParams()
    if u is not None:
        robot = replace(params.pair.robot, u=u)
        params = replace(params, pair=replace(params.pair, robot=robot))
    python, fast = DecisionModel(params, LAYOUT), DecisionModel(params, LAYOUT)
    fast.use_compiled()
    for model in (python, fast):
        model.reset("consensus" if option else "dissensus", option)
    want = python._run(z_r, b_r, z_hat, n, h)
    assert bits(*fast._run(z_r, b_r, z_hat, n, h)) == bits(*want)
    assert bits(*rk4_pair(z_r, b_r, z_hat, n, h, -params.pair.robot.d, params.pair.robot.u,
                          params.pair.robot.alpha,
                          params.pair.robot.gamma * params.pair.a_rh * z_hat,
                          option is not None, python._sigma, python._beta, python.b_star,
                          params.bias.b_max)[:2]) == bits(*want)


def per_step_advance(self: Participant, t: float, dt: float = 0.002) -> None:
    """`Participant.advance` as it was: `_step` called for every step of h (no fused loop)."""
    if self.t_go is None or self.pressed is not None:
        self.t = max(self.t, t)
        return
    if self.t < self.t_go:
        self.t = min(t, self.t_go)
    step = self._step_general if self.general else self._step
    while self.t < t - 1e-12:
        left = t - self.t
        h = left if left < dt else dt
        step(h)
        self.t += h


@pytest.mark.parametrize("no_jit", ["0", "1"])
@pytest.mark.parametrize("spec_person", [False, True])
@pytest.mark.parametrize("seed", [1, 2, 3, 5, 8, 13, 21, 34])
def test_the_compiled_loop_changes_no_session(monkeypatch, seed, spec_person, no_jit):
    """The fitted person's sessions (its strategists' feints and contrarians included) and the
    SPEC person's, every recorded sample, are the same with the fused steps (the decision's
    `rk4_pair`, the participant's `person_steps`, the arm's substeps), compiled and as Python
    (`NOD_NO_JIT=1`), as with the model's steps (a `_step` call per step)."""
    monkeypatch.setenv("NOD_NO_JIT", no_jit)
    cfg = NodConfig() if spec_person else load_cohort_params(None)
    fast = run_offline_session(cfg, seed, cohort=True, record=True)
    for part in (DecisionModel, Participant, PointArm):
        monkeypatch.setattr(part, "use_compiled", lambda self: None)
    monkeypatch.setattr(Participant, "advance", per_step_advance)
    plain = run_offline_session(cfg, seed, cohort=True, record=True)
    assert len(fast) == 8 and repr(fast) == repr(plain)


@settings(max_examples=2000, deadline=None)
@given(
    x=st.one_of(st.floats(allow_nan=False, allow_infinity=False), st.just(0.0), st.just(-0.0)),
    y=st.one_of(st.floats(-10.0, 10.0), st.floats(allow_nan=False, allow_infinity=False),
                st.just(0.0), st.floats(-1e-300, 1e-300)),
)
def test_python_hypot_compiled_is_math_hypot(x, y):
    """The compiled steps' `py_hypot` is CPython's `math.hypot` (not the C library's), subnormal
    and huge arguments included, compiled and as Python."""
    want = math.hypot(x, y)
    assert py_hypot(x, y).hex() == want.hex()
    assert hypot_kernel()(x, y).hex() == want.hex()


def test_python_hypot_on_a_million_pairs():
    rng = np.random.default_rng(35)
    xs = rng.normal(0.0, 1.0, 10**6) * rng.choice([1e-310, 1e-9, 1e-3, 0.3, 5.0], 10**6)
    ys = rng.normal(0.0, 1.0, 10**6) * rng.choice([1e-310, 1e-9, 1e-3, 0.3, 5.0], 10**6)
    hypot = hypot_kernel()
    assert all(hypot(x, y) == math.hypot(x, y) for x, y in zip(xs.tolist(), ys.tolist(),
                                                                 strict=True))


@pytest.mark.parametrize("option", [None, "red"])
@pytest.mark.parametrize("start", [(0.0, 0.0, 0.0), (0.0, 0.0, -0.0), (0.4, 0.0, -0.3)])
def test_a_fixed_point_is_held_bit_for_bit(option, start):
    """At rest (all zeros, before "go") and after convergence the steps stop being computed."""
    model = DecisionModel(DecisionParams(), LAYOUT)
    model.reset("consensus" if option else "dissensus", option)
    z_r, b_r, z_hat = start
    for _ in range(3):  # converge (~5000 steps: d = 10/s, 1 ms), then go on from there
        path: list[tuple[float, float]] = []
        end = model._run(z_r, b_r, z_hat, 5000, 1e-3, path)
        want = plain_run(model, z_r, b_r, z_hat, 5000, 1e-3)
        assert [bits(*s) for s in path] == [bits(*s) for s in want]
        z_r, b_r = end


def plain_z_step(p: ParticipantParams, z: float, r_hat: float, b: float, h: float) -> float:
    a = p.agent

    def f(y: float) -> float:
        return opinion_rate(y, r_hat, b, a.d, a.u, a.alpha, a.gamma, math.tanh)

    return rk4_step(f, z, h)


@settings(max_examples=200, deadline=None)
@given(
    z=finite,
    r_hat=st.sampled_from([-1.0, 0.0, 1.0]),
    b=st.floats(-5.0, 5.0),
    h=st.sampled_from([0.002, 0.0013333, 1e-4]),
)
def test_the_participants_opinion_step_is_rk4_of_eq2_bit_for_bit(z, r_hat, b, h):
    person = Participant(ParticipantParams(), LAYOUT, seed=1)
    person.new_trial("red")
    person.go(0.0)
    person.t = 0.0  # before the reaction time: the step moves the opinion, not the hand
    person.z_h, person.b_h = z, b
    person._last_box = {1.0: 0, -1.0: 1, 0.0: None}[r_hat]  # the arm seen at red, blue, still
    person._step(h)
    assert bits(person.z_h) == bits(plain_z_step(person.p, z, r_hat, b, h))


@settings(max_examples=300, deadline=None)
@given(x=st.floats(0.0, 1.0), y=st.floats(0.0, 1.0))
def test_the_press_test_is_the_layouts_on_the_noise_free_landmarks(x, y):
    person = Participant(ParticipantParams(), LAYOUT, seed=1)
    person._x, person._y = x, y
    pts = [(float(u), float(v)) for u, v in person.landmarks(noise=False)]
    assert person._press_test() == LAYOUT.pressed(pts)


class PlainArm(SimArm):
    """The arm with every substep computed, at rest or not."""

    def advance(self, t: float) -> None:
        span = t - self._t
        if span == 0:
            return
        n = max(1, math.ceil(span / self.params.step_s))
        for i in range(1, n + 1):
            self._substep(span / n, self._t + span * i / n)
        self._t = t


def arm_state(arm: SimArm, t: float) -> tuple:
    s = arm.state(t)
    return (*bits(*s.ee), s.moving, s.target, s.pressed, bits(*arm.velocity))


commands = st.lists(
    st.tuples(
        st.floats(0.001, 1.5),
        st.sampled_from(["move 1", "move -1", "press red", "press blue", "stop", "home"]),
    ),
    max_size=8,
)


def play(what: str, *arms: SimArm) -> None:
    """One of `commands`' words, given to each arm."""
    for arm in arms:
        if what == "home":
            arm.home()
        elif what == "stop":
            arm.send(ArmCommand.stop("test"))
        else:
            action, to = what.split()
            arm.send(
                ArmCommand.move(int(to), "test")
                if action == "move"
                else ArmCommand.press(to, "test")  # type: ignore[arg-type]
            )


@pytest.mark.parametrize("compiled", [False, True])
@settings(max_examples=100, deadline=None)
@given(script=commands)
def test_an_arm_at_rest_skips_no_change(compiled, script):
    """Moves, presses held at rest, stops and homecomings: the states of every 33 ms frame,
    with the Python substeps skipped at rest and with the compiled substeps."""
    fast, plain = SimArm(LAYOUT), PlainArm(LAYOUT)
    if compiled:
        fast.use_compiled()
    fast.connect()
    plain.connect()
    t = 0.0
    for wait, what in [*script, (2.0, "stop")]:
        play(what, fast, plain)
        end = t + wait
        while t < end:
            t = min(end, t + 1 / 30)
            assert arm_state(fast, t) == arm_state(plain, t)


@settings(max_examples=50, deadline=None)
@given(script=commands)
def test_the_loops_glance_is_the_arms_state(script):
    """`glance` (the offline loop's read of the arm) gives the fields `state` reports."""
    glanced, reported = SimArm(LAYOUT), SimArm(LAYOUT)
    t = 0.0
    for arm in (glanced, reported):
        arm.connect()
    for wait, what in [*script, (2.0, "stop")]:
        play(what, glanced, reported)
        end = t + wait
        while t < end:
            t = min(end, t + 1 / 30)
            ee, moving, target, pressed = glanced.glance(t)
            s = reported.state(t)
            assert (bits(*ee), moving, target, pressed) == (bits(*s.ee), s.moving, s.target,
                                                            s.pressed)


def test_centre_is_numpys_mean_bit_for_bit():
    rng = np.random.default_rng(3)
    for n in (1, 2, 7, 8, 9, 16, 21, 40):
        for _ in range(200):
            pts = rng.uniform(0.0, 1.0, (n, 2)) * rng.choice([1e-3, 1.0, 1e3])
            assert bits(*centre(pts)) == bits(pts[:, 0].mean(), pts[:, 1].mean())


@pytest.mark.parametrize("n_options", [2, 3])
@pytest.mark.parametrize("seed", [2, 7])
def test_the_press_pre_test_changes_no_session(monkeypatch, seed, n_options):
    """Judge and robot asked about every pose (boxes as wide as the table) give the same run,
    on the paper's table and on one of three boxes alike."""
    cfg = NodConfig()
    schedule = None if n_options == 2 else OptionsSchedule.default(n_options)
    fast = run_offline_session(cfg, seed, cohort=True, record=True, schedule=schedule)
    everywhere = (-math.inf, math.inf, -math.inf, math.inf)
    monkeypatch.setattr(closed_loop, "box_bounds", lambda boxes: [everywhere] * len(boxes))
    plain = run_offline_session(cfg, seed, cohort=True, record=True, schedule=schedule)
    assert len(fast) == 8 and repr(fast) == repr(plain)


@pytest.mark.parametrize("record", [True, False])
@pytest.mark.parametrize("n_options", [2, 3])
@pytest.mark.parametrize(
    ("seed", "breaks"), [(1, None), (4, None), (9, {(2, 1): 2.5, (5, 1): 0.2, (6, 1): 5.0})]
)
def test_frames_nobody_reads_change_no_session(monkeypatch, seed, breaks, n_options, record):
    """Poses between a trial's setup and its "go", and once both have pressed (after the
    "end" when samples are recorded), are neither made nor fed to the decision engine
    (`_Loop._idle`: nothing reads them): fed every pose, the fitted person's session (trials,
    presses, times, every recorded sample) is the same, on two and three boxes, interruptions
    and repeats included."""
    cfg = load_cohort_params(None)
    schedule = None if n_options == 2 else OptionsSchedule.default(n_options)
    fed: list[int] = []
    engine = DecisionModel if n_options == 2 else OptionsDecision
    on_hand = engine.on_hand

    def counted(self, t_ns, landmarks):
        fed.append(t_ns)
        return on_hand(self, t_ns, landmarks)

    monkeypatch.setattr(engine, "on_hand", counted)
    fast = run_offline_session(cfg, seed, cohort=True, record=record, breaks=breaks,
                               schedule=schedule)
    skipping = len(fed)
    monkeypatch.setattr(closed_loop._Loop, "_idle", lambda self: False)
    plain = run_offline_session(cfg, seed, cohort=True, record=record, breaks=breaks,
                                schedule=schedule)
    assert len(fast) == 8 and repr(fast) == repr(plain)
    assert skipping < 0.7 * (len(fed) - skipping)  # countdowns and rests were skipped


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31), common=st.sampled_from([0.0, 0.003, 0.01]),
       each=st.sampled_from([0.0, 0.001]), frames=st.integers(1, 5))
def test_an_unseen_frame_draws_what_landmarks_draw(seed, common, each, frames):
    """An idle frame's `unseen` takes the random stream where `landmarks` would: after it, every
    later draw (the next frame's landmarks, a trial's preference) is the same."""
    params = ParticipantParams(common_noise=common, landmark_noise=each)
    seen, unseen = (Participant(params, LAYOUT, seed=seed) for _ in range(2))
    for _ in range(frames):
        seen.landmarks()
        unseen.unseen()
    assert seen.rng.bit_generator.state == unseen.rng.bit_generator.state
    assert bits(*seen.landmarks().ravel()) == bits(*unseen.landmarks().ravel())


@settings(max_examples=300, deadline=None)
@given(seed=st.integers(0, 2**31),
       x=st.one_of(st.floats(-0.3, 1.3), st.sampled_from([0.0, -0.0, 1.0])),
       y=st.one_of(st.floats(-0.3, 1.3), st.sampled_from([0.0, -0.0, 1.0])),
       common=st.sampled_from([0.0, 0.003, 0.05, 0.5]),
       each=st.sampled_from([0.0, 0.001, 0.2]))
def test_the_compiled_camera_is_numpys_landmarks_bit_for_bit(seed, x, y, common, each):
    """`compiled.camera_landmarks` gives `Participant.landmarks`' NumPy values to the bit (a
    zero's sign included, hands at and past the image's edges, where the clip decides) from the
    same draws, leaving the random stream where NumPy leaves it."""
    params = ParticipantParams(common_noise=common, landmark_noise=each)
    plain, fast = (Participant(params, LAYOUT, seed=seed) for _ in range(2))
    fast.use_compiled()
    assert fast._camera is not None  # noqa: SLF001 - the compiled camera is what is tested
    for person in (plain, fast):
        person._x, person._y = x, y  # noqa: SLF001 - a hand anywhere, the edges included
    for _ in range(3):
        assert bits(*fast.landmarks().ravel()) == bits(*plain.landmarks().ravel())
    assert fast.rng.bit_generator.state == plain.rng.bit_generator.state


@settings(max_examples=400, deadline=None)
@given(rows=st.integers(8, 128), seed=st.integers(0, 2**31),
       scale=st.sampled_from([1e-3, 0.3, 1.0, 1e3]), offset=st.floats(-2.0, 2.0),
       bounds=st.lists(st.tuples(*[st.floats(-1.0, 2.0)] * 4), min_size=0, max_size=5))
def test_the_compiled_pose_view_is_the_loops_bit_for_bit(rows, seed, scale, offset, bounds):
    """`compiled.pose_view` (the offline loop's landmarks' centre and box pre-test) gives
    `view_of`'s values: NumPy's pairwise mean to the bit for any count it is used at (8-128,
    every remainder of the blocks of eight), and the same reach for boxes anywhere."""
    pts = offset + scale * np.random.default_rng(seed).standard_normal((rows, 2))
    boxes = [(x1, x2, y1, y2) for x1, x2, y1, y2 in bounds]
    array = np.array(boxes, dtype=np.float64).reshape(len(boxes), 4)
    cx, cy, reach = view_kernel()(pts, array)
    px, py, preach = view_of(pts, boxes)
    assert bits(cx, cy) == bits(px, py) and reach == preach
    assert (cx, cy) == centre(pts)


def test_the_pose_view_reaches_exactly_the_boxes_a_landmark_can_be_in():
    """On the paper's table: the hand at a box's edge reaches it, a hair outside does not."""
    red = LAYOUT.red
    bounds = [(red.x1, red.x2, red.y1, red.y2)]
    array = np.array(bounds)
    at_edge = np.full((21, 2), (red.x2, (red.y1 + red.y2) / 2))
    outside = at_edge + (1e-12, 0.0)
    for pts, expected in ((at_edge, True), (outside, False)):
        assert view_kernel()(pts, array)[2] is expected
        assert view_of(pts, bounds)[2] is expected
