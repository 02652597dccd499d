"""The offline loop's numeric inner loops, compiled with Numba: the same floats, faster.

A cohort (`nod cohort`, `nod calibrate-cohort`, `nod analyze power`, the fit's reference
table) runs the offline closed loop once per simulated person, and must give the same sessions
for the same seeds whatever runs it (tests/unit/test_golden.py, the stored rows' SHA-256 of
benchmarks/cohort_speed.py). Three loops of plain float arithmetic were most of a session's
CPU (docs/scale.md): the decision engine's RK4 of eqs 1 and 6 (`rk4_pair`, ~33 steps of 1 ms
per camera frame), the participant's 2 ms steps on two boxes (`person_steps`: eq 2, the arm
as seen, the hand, the press test, a feint's turn) and the simulated arm's substeps
(`arm_steps`). Each is plain Python that Numba compiles as it is. The first two (and eq 2's
RK4 step, `eq2_step`, which both call) are the only copy of their arithmetic: `DecisionModel`
and `Participant` call them as Python (the rig, `NOD_NO_JIT=1`) and the offline loop calls them
compiled. `arm_steps` is written once more, operation for operation `arm_kinematics`' loop,
and so are the camera's noisy view of the hand (`camera_landmarks`, NumPy's expression
element by element) and what the frame reads of it (`pose_view`: the landmarks' mean by
NumPy's pairwise summation, and the press pre-test): one call each a frame where Python
made five, together a fifth of a session.
The reference the tests hold them to is the model as stated: `opinion_rate` and `bias_rate`,
`Participant._step` (one call a step), the arm's `_substep`.

Why these are the same bits as the Python loops:

- `+ − × ÷`, `sqrt`, comparisons, `abs` and `copysign` are IEEE operations, correctly rounded
  in both, and every one is written in the Python loop's order.
- No `fastmath`: LLVM may then neither reassociate nor contract a product and a sum into one
  fused multiply-add (an FMA rounds once where Python rounds twice).
- `math.tanh` compiles to a call of the C library's `tanh`, which is what CPython's
  `math.tanh` calls (NumPy's SIMD `tanh` is another algorithm and differs in the last bit).
- `math.hypot` and `math.dist` are not the C library's `hypot` in CPython but its own
  `vector_norm` (glibc's `hypot` differs from it in the last bit on ~0.6 % of pairs): ported
  as `py_hypot`, checked against `math.hypot` by tests/unit/test_loop_speed.py.
- Python's `max(0.0, m)` and `min(a, b, c)` keep the first of equals; they are written as the
  comparisons they make, so a −0.0 cannot come out where Python gives +0.0.

tests/unit/test_loop_speed.py holds each kernel, compiled and as Python, to that reference bit
for bit (`float.hex`, so a zero's sign counts) and whole sessions of the fitted and the SPEC
person to the all-Python loop's, every recorded sample included.

Compiled once per machine and kept on disk next to this file (`cache=True`, __pycache__; ~2 s
on a fresh clone), then loaded by each process that runs the offline loop (~0.5 s with
Numba's import: a Dask worker, a test process). Only the offline loop turns them on
(`use_compiled` on its parts, `closed_loop`); the rig's services keep the Python parts and
never import Numba. `NOD_NO_JIT=1` keeps the offline loop on the Python parts too (the same
sessions, ~2× slower).
"""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Callable
from types import FunctionType
from typing import Any, cast

RK4Pair = Callable[
    [float, float, float, int, float, float, float, float, float, bool, float, float, float,
     float],
    tuple[float, float, bool],
]


def eq2_step(z: float, h: float, nd: float, u: float, alpha: float, gr: float, b: float) -> float:
    """One RK4 step of h of eq 2 (or eq 1 with its bias held) from z, the social input held.

    ż = −d z + u tanh(α z + γ r) + b, `opinion_rate` written out with the same float operations
    in the same order (−d as `nd`, γ r hoisted as `gr`: both held through the step). The one
    copy of this step: the participant's (`Participant._step`, `person_steps`) and the
    engine's with b_r frozen (`rk4_pair`). Plain Python: Numba compiles
    it into the kernels that call it.
    """
    tanh = math.tanh
    hh = 0.5 * h
    k1 = nd * z + u * tanh(alpha * z + gr) + b
    z2 = z + hh * k1
    k2 = nd * z2 + u * tanh(alpha * z2 + gr) + b
    z3 = z + hh * k2
    k3 = nd * z3 + u * tanh(alpha * z3 + gr) + b
    z4 = z + h * k3
    k4 = nd * z4 + u * tanh(alpha * z4 + gr) + b
    return z + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


def rk4_pair(
    z_r: float,
    b_r: float,
    z_hat: float,
    n: int,
    h: float,
    nd: float,
    u: float,
    alpha: float,
    gz: float,
    consensus: bool,
    sigma: float,
    beta: float,
    b_star: float,
    b_max: float,
) -> tuple[float, float, bool]:
    """Take n RK4 steps of h of eqs 1 and 6 from (z_r, b_r), ẑ_h held: `DecisionModel._run`.

    The equations are `opinion_rate` (eq 1) and `bias_rate` (eq 6), the functions the analysis
    and the tests use, written out here with the same float operations in the same order (so
    every value is bit for bit theirs; tests/unit/test_loop_speed.py checks it) and their
    constant parts hoisted (−d as `nd`, γ_r a_rh ẑ_h as `gz` and the sign of ẑ_h: ẑ_h is held).
    The RK4 stages are written out for the pair (z_r, b_r) on plain floats because this runs ~8
    steps per pose at 120 Hz (~33 at 30 Hz, ~1000 steps per simulated second), where a generic
    stepper's tuples, NumPy's per-call overhead, or even a function call per stage (half the
    step's cost) would dominate. Returns the state and whether the steps stopped at an exact
    fixed point of the step (every later step would return it too). The one copy of these
    steps: `_run` calls it as Python (the rig, `NOD_NO_JIT=1`) and Numba compiles this very
    function for the offline loop (`pair_kernel`).
    """
    tanh = math.tanh
    copysign = math.copysign
    sgn = 1.0 if z_hat > 0 else -1.0  # `bias_rate`'s sign of ẑ_h, held with it
    hh, h6 = 0.5 * h, h / 6.0
    for _ in range(n):
        z0, b0 = z_r, b_r
        # The freeze (eq 6 runs only while z_r · ẑ_h < 0) is decided once per step from the
        # state at its start: switching it inside the RK4 stages would make the right-hand side
        # discontinuous within a step and spoil the method's accuracy; the step is short (1 ms)
        # against the dynamics' time constants (1/d = 100 ms).
        if consensus and z_r * z_hat < 0:  # `bias_active`: the pair is in dissensus
            # `max(0.0, m)` written as the comparison Python's `max` makes
            k1z = nd * z_r + u * tanh(alpha * z_r + gz) + b_r
            m = b_star - abs(b_r)
            k1b = sigma * z_r * sgn + beta * (m if m > 0.0 else 0.0)
            z2, b2 = z_r + hh * k1z, b_r + hh * k1b
            k2z = nd * z2 + u * tanh(alpha * z2 + gz) + b2
            m = b_star - abs(b2)
            k2b = sigma * z2 * sgn + beta * (m if m > 0.0 else 0.0)
            z3, b3 = z_r + hh * k2z, b_r + hh * k2b
            k3z = nd * z3 + u * tanh(alpha * z3 + gz) + b3
            m = b_star - abs(b3)
            k3b = sigma * z3 * sgn + beta * (m if m > 0.0 else 0.0)
            z4, b4 = z_r + h * k3z, b_r + h * k3b
            k4z = nd * z4 + u * tanh(alpha * z4 + gz) + b4
            m = b_star - abs(b4)
            k4b = sigma * z4 * sgn + beta * (m if m > 0.0 else 0.0)
            b_r += h6 * (k1b + 2.0 * k2b + 2.0 * k3b + k4b)
            # Clamp |b_r| ≤ b_max after each step (SPEC §3): in dissensus the σ term never stops
            # on its own.
            if b_r > b_max:
                b_r = b_max
            elif b_r < -b_max:
                b_r = -b_max
            z_r += h6 * (k1z + 2.0 * k2z + 2.0 * k3z + k4z)
        else:  # b_r frozen: only z_r moves, eq 1 alone
            z_r = eq2_step(z_r, h, nd, u, alpha, gz, b_r)
        if (  # a fixed point of the step, bit for bit (the sign of a zero included)
            z_r == z0
            and b_r == b0
            and copysign(1.0, z_r) == copysign(1.0, z0)
            and copysign(1.0, b_r) == copysign(1.0, b0)
        ):
            # The step is a function of (z_r, b_r) alone (ẑ_h, h and the mode are held), so
            # every later step returns this state too. Held hands (before "go", after a press,
            # a still participant) get here.
            return z_r, b_r, True
    return z_r, b_r, False


def enabled() -> bool:
    """Whether the offline loop takes the compiled steps (`NOD_NO_JIT=1`: the Python parts')."""
    return os.environ.get("NOD_NO_JIT") != "1"


def _jit(fn: Callable[..., Any], **calls: Callable[..., Any]) -> Any:
    """Compile fn, its calls of `calls` resolved to those compiled functions.

    Numba (imported here: only the offline loop pays for it) compiles `fn` itself, its code
    unchanged, with no `fastmath`; `cache=True` keeps the machine code on disk next to this
    file (__pycache__), so the next process (a Dask worker, a test) loads it instead.
    """
    from numba import njit

    jit = njit(cache=True, nogil=True)
    if calls:  # compiled code calls compiled code: the same code, with compiled globals
        fn = FunctionType(fn.__code__, {**fn.__globals__, **{k: jit(f) for k, f in
                                                            calls.items()}}, fn.__name__)
    return jit(fn)


_kernels: dict[str, Any] = {}


def _kernel(fn: Callable[..., Any], **calls: Callable[..., Any]) -> Any:
    """`_jit(fn, **calls)`, once per process."""
    kernel = _kernels.get(fn.__name__)
    if kernel is None:
        kernel = _kernels[fn.__name__] = _jit(fn, **calls)
    return kernel


def pair_kernel() -> RK4Pair:
    """`rk4_pair` compiled (once per process)."""
    return cast(RK4Pair, _kernel(rk4_pair, eq2_step=eq2_step))


# -- the participant's steps on two boxes ---------------------------------------------------------

_DBL_MIN = 2.2250738585072014e-308  # the smallest normal double
# How CPython's `vector_norm` treats a subnormal largest argument: 3.11 divides by it, 3.12 on
# scale both to normal numbers first (exactly) and the result back. Normal arguments: one code.
_RESCALE_SUBNORMALS = sys.version_info >= (3, 12)
_VELTKAMP = 134217729.0  # 2**27 + 1: splits a double into two halves whose products are exact


def py_hypot(x: float, y: float) -> float:
    """CPython's `math.hypot(x, y)` for finite x and y, bit for bit (`vector_norm`).

    Not the C library's `hypot` (glibc's differs from Python's in the last bit on ~0.6 % of
    arguments): Python scales by a power of two (exact), squares exactly (a product and its
    rounding error: Dekker's split here, as CPython 3.11's `dl_mul`; 3.12's `fma` gives the
    same exact error), sums with compensation and corrects the square root once. A subnormal
    larger argument is treated as the running Python treats it (`_RESCALE_SUBNORMALS`; checked
    on 3.11, 3.12 and 3.13 as Python). tests/unit/test_loop_speed.py checks it against
    `math.hypot` (zeros, subnormals and 10⁻¹² to 10 included).
    """
    ax = abs(x)
    ay = abs(y)
    mx = ay if ay > ax else ax  # the larger; 0.0 if both are zeros
    if mx == 0.0:
        return mx
    e = math.frexp(mx)[1]
    post = 1.0
    if e < -1023:  # a subnormal maximum
        if not _RESCALE_SUBNORMALS:  # 3.11: divide by the maximum
            csum = 1.0
            frac = 0.0
            for v in (ax / mx, ay / mx):
                v = v * v
                old = csum
                csum += v
                frac += (old - csum) + v
            return mx * math.sqrt(csum - 1.0 + frac)
        ax, ay, mx = ax / _DBL_MIN, ay / _DBL_MIN, mx / _DBL_MIN  # 3.12: normal, exactly
        e = math.frexp(mx)[1]
        post = _DBL_MIN
    scale = math.ldexp(1.0, -e)
    csum = 1.0
    frac1 = 0.0
    frac2 = 0.0
    for v in (ax * scale, ay * scale):  # lossless scaling
        p = v * v
        t = v * _VELTKAMP
        hi = t - (t - v)
        lo = v - hi
        frac1 += ((hi * hi - p) + hi * lo + lo * hi) + lo * lo  # the square's rounding error
        s = csum + p  # dl_fast_sum(csum, p)
        frac2 += (csum - s) + p
        csum = s
    h = math.sqrt(csum - 1.0 + (frac1 + frac2))
    nh = -h
    p = nh * h
    t = nh * _VELTKAMP
    nh_hi = t - (t - nh)
    nh_lo = nh - nh_hi
    t = h * _VELTKAMP
    h_hi = t - (t - h)
    h_lo = h - h_hi
    frac1 += ((nh_hi * h_hi - p) + nh_hi * h_lo + nh_lo * h_hi) + nh_lo * h_lo
    s = csum + p
    frac2 += (csum - s) + p
    csum = s
    h += (csum - 1.0 + (frac1 + frac2)) / (2.0 * h)  # the differential correction
    return post * (h / scale)  # × 1.0 is exact: only a subnormal maximum changes it


# What stopped `person_steps`: t reached (or a press), an arm sighting is due.
DONE, SEEN = 0, 1

# `person_steps`' state vector (float64; a box index, −1 for None, and flags as floats).
S_T, S_Z, S_X, S_Y, S_VX, S_VY, S_LAST, S_ARM, S_OPPOSED, S_FIRST, S_HEADING, S_SWITCHES, \
    S_QUICK, S_PRESSED, S_FEINT = range(15)
S_SIZE = 15
# Its constants of a trial (after "go").
(C_B, C_ND, C_U, C_ALPHA, C_GAMMA, C_TMOVE, C_DELAY, C_CUE, C_AGAINST, C_FULL, C_LEAST,
 C_SPEED, C_LATE, C_ACCEL, C_COMMIT_Y, C_BELOW, C_OBEYS, C_MAX_SWITCHES) = range(18)
C_CENTERS = 18  # box 0's centre (x, y), then box 1's
C_NEAR = 22  # box 0's (x1, x2, y1, y2) where a landmark can be inside, then box 1's
C_BOXES = 30  # box 0's (x1, x2, y1, y2), then box 1's: the press test's boxes
C_HAND = 38  # the 21 landmarks (x, y) around a zero centre (`Participant._hand`)
C_LINE = 80  # the feint's turn (`_turn_at_the_line`): the commit line's y, hand below, the lead
C_SIZE = 83

# CPython's `math.hypot`, as `person_steps` calls it as Python (the rig, `NOD_NO_JIT=1`); its
# compiled copy calls `py_hypot`, the port of it, in its place (`person_kernel`).
hypot = math.hypot


def pressed_box(x: float, y: float, c: Any) -> int:
    """`Participant._press_test` once near a box: the box a noise-free landmark is in, or −1.

    The landmarks as `landmarks(noise=False)` makes them (the template plus the centre, each
    an IEEE sum like NumPy's, clipped to [0, 1]), tested as `OptionsLayout.pressed` tests them:
    landmark by landmark, box 0 before box 1, edges included. Clipping to 0.0 or 1.0 by a
    comparison can only differ from NumPy's in a zero's sign, which no comparison sees.
    """
    for i in range(21):
        px = c[C_HAND + 2 * i] + x
        py = c[C_HAND + 2 * i + 1] + y
        if px < 0.0:
            px = 0.0
        elif px > 1.0:
            px = 1.0
        if py < 0.0:
            py = 0.0
        elif py > 1.0:
            py = 1.0
        for j in range(2):
            k = C_BOXES + 4 * j
            if c[k] <= px <= c[k + 1] and c[k + 2] <= py <= c[k + 3]:
                return j
    return -1


def person_steps(t: float, dt: float, s: Any, c: Any, next_seen: float) -> int:
    """`Participant.advance` on two boxes: `_step` (with `_arm_seen` and `_move`) fused.

    The same steps of h as `advance` takes with `_step`, the same float operations in the same
    order, so the same values bit for bit (tests/unit/test_loop_speed.py runs whole sessions
    both ways); a feint's turn at the line included. The state `s` (S_*, a list as Python, an
    array compiled) is updated in place; `c` holds the trial's constants (C_*). Stops before a
    step whose start sees a new arm sighting due (`next_seen` ≤ t − delay: SEEN; the caller
    pops the person's queue and calls again) and after a step that brings the hand's centre
    near a box, the press test (`pressed_box`); after a press only the clock goes on. Plain
    Python: `Participant` calls it as it is (`math.hypot`), and Numba compiles it for the
    offline loop (`person_kernel`, `py_hypot`); the opinion, the hand and the clock live in
    locals, the trial's constants are read once (this loop was a third of a cohort's CPU).
    """
    tt, z, x, y, vx, vy = s[S_T], s[S_Z], s[S_X], s[S_Y], s[S_VX], s[S_VY]
    last_box, arm_box = int(s[S_LAST]), int(s[S_ARM])
    opposed, first = s[S_OPPOSED], int(s[S_FIRST])
    heading, switches, quick = int(s[S_HEADING]), int(s[S_SWITCHES]), s[S_QUICK] != 0.0
    feint = s[S_FEINT] != 0.0
    b, nd, u, alpha, gamma = c[C_B], c[C_ND], c[C_U], c[C_ALPHA], c[C_GAMMA]
    t_move, delay, cue, against = c[C_TMOVE], c[C_DELAY], int(c[C_CUE]), c[C_AGAINST]
    full, least, accel = c[C_FULL], c[C_LEAST], c[C_ACCEL]
    speed = c[C_SPEED] * (c[C_LATE] if quick else 1.0)  # `_move`'s, fixed unless a feint turns
    commit_y, below, obeys = c[C_COMMIT_Y], c[C_BELOW] != 0.0, c[C_OBEYS] != 0.0
    max_switches = int(c[C_MAX_SWITCHES])
    line_y, line_below, ahead = c[C_LINE], c[C_LINE + 1] != 0.0, c[C_LINE + 2]
    cx0, cy0, cx1, cy1 = c[C_CENTERS], c[C_CENTERS + 1], c[C_CENTERS + 2], c[C_CENTERS + 3]
    ax1, ax2, ay1, ay2 = c[C_NEAR], c[C_NEAR + 1], c[C_NEAR + 2], c[C_NEAR + 3]
    bx1, bx2, by1, by2 = c[C_NEAR + 4], c[C_NEAR + 5], c[C_NEAR + 6], c[C_NEAR + 7]
    end = t - 1e-12
    event = DONE
    while tt < end:
        left = t - tt
        h = left if left < dt else dt  # min(dt, left)
        if next_seen <= tt - delay:  # `_arm_seen` would pop a sighting: the caller does
            event = SEEN
            break
        if last_box < 0:
            r_hat = 0.0
        else:
            arm_box = last_box
            if first >= 0 and last_box != first:
                opposed = 1.0
            weight = against if cue >= 0 and last_box != cue else 1.0
            r_hat = weight if last_box == 0 else -weight
        z = eq2_step(z, h, nd, u, alpha, gamma * r_hat, b)  # eq 2, one RK4 step
        start = tt
        tt = tt + h
        if start < t_move:  # `_step`'s reaction test (its self.t is the step's start)
            continue
        # `_move(h, 0 if z > 0 else 1, abs(z))`
        wanted = 0 if z > 0 else 1
        lead = abs(z)
        committed = heading >= 0 and (
            quick
            or switches >= max_switches
            or (obeys and (y < commit_y if below else y > commit_y))
        )
        if heading < 0:
            heading = wanted
            first = wanted
        elif feint:  # `_turn_at_the_line`: decided once, at the line
            if (y + ahead < line_y) if line_below else (y + ahead > line_y):
                feint = False
                if arm_box >= 0 and arm_box != heading:
                    heading = arm_box
                    switches += 1
                    quick = True
                    speed = c[C_SPEED] * c[C_LATE]
        elif wanted != heading and not committed:
            heading = wanted
            switches += 1
        if heading == 0:
            dx, dy = cx0 - x, cy0 - y
        else:
            dx, dy = cx1 - x, cy1 - y
        dist = hypot(dx, dy)
        if committed or feint:  # read after the turn, as `_move` reads it
            conviction = 1.0
        else:  # min(1, max(min_conviction, lead / full_conviction)), without the calls
            conviction = lead / full
            if not conviction > least:
                conviction = least
            if not conviction < 1.0:
                conviction = 1.0
        gain = speed * conviction / (1e-9 if dist < 1e-9 else dist)
        ax, ay = dx * gain - vx, dy * gain - vy
        dv = hypot(ax, ay)
        max_dv = accel * h
        if dv > max_dv:
            ax, ay = ax * max_dv / dv, ay * max_dv / dv
        vx, vy = vx + ax, vy + ay
        x, y = x + vx * h, y + vy * h
        if (ax1 <= x <= ax2 and ay1 <= y <= ay2) or (bx1 <= x <= bx2 and by1 <= y <= by2):
            pressed = pressed_box(x, y, c)
            if pressed >= 0:  # at rest from here: the clock alone goes on
                s[S_PRESSED] = pressed
                while tt < end:
                    left = t - tt
                    tt += left if left < dt else dt
                break
    s[S_T], s[S_Z], s[S_X], s[S_Y], s[S_VX], s[S_VY] = tt, z, x, y, vx, vy
    s[S_ARM], s[S_OPPOSED], s[S_FIRST] = arm_box, opposed, first
    s[S_HEADING], s[S_SWITCHES], s[S_QUICK], s[S_FEINT] = heading, switches, quick, feint
    return event


PersonSteps = Callable[[float, float, Any, Any, float], int]


def person_kernel() -> PersonSteps:
    """`person_steps` compiled (once per process), `py_hypot` for `math.hypot`."""
    return cast(PersonSteps, _kernel(person_steps, hypot=py_hypot, pressed_box=pressed_box,
                                     eq2_step=eq2_step))


# -- the simulated arm's substeps ---------------------------------------------------------------

# `arm_steps`' state vector: position, velocity, the goal (and whether there is one), whether a
# press is committed, whether it is done, when the hold began (and whether it has).
A_X, A_Y, A_VX, A_VY, A_GX, A_GY, A_GOAL, A_PRESS, A_PRESSED, A_STARTED, A_HAS_STARTED = range(11)
A_SIZE = 11
_ARRIVED = 1e-6  # `arm_kinematics._ARRIVED`


def arm_steps(
    t0: float, span: float, n: int, s: Any, max_speed: float, max_accel: float, hold_s: float
) -> None:
    """`PointArm.advance`'s n substeps over `span` from t0 (`_substep`, `_update_press`).

    The state `s` (A_*) is updated in place. The same operations in the same order as
    `arm_kinematics`, `py_hypot` for `math.hypot` and for `math.dist` (which is CPython's
    same `vector_norm` of the coordinates' differences).
    """
    x, y, vx, vy = s[A_X], s[A_Y], s[A_VX], s[A_VY]
    gx, gy, goal = s[A_GX], s[A_GY], s[A_GOAL] != 0.0
    press, pressed = s[A_PRESS] != 0.0, s[A_PRESSED] != 0.0
    started, has_started = s[A_STARTED], s[A_HAS_STARTED] != 0.0
    dt = span / n
    dv_max = max_accel * dt
    for i in range(1, n + 1):
        t_end = t0 + span * i / n
        if vx == 0.0 and vy == 0.0 and (not goal or (x == gx and y == gy)):
            if not press or pressed or not goal:
                break  # at rest where it should be: nothing changes any more
        else:  # `_substep`
            if not goal:
                dx_, dy_ = 0.0, 0.0
            else:
                dx, dy = gx - x, gy - y
                dist = py_hypot(dx, dy)
                if dist < _ARRIVED:
                    dx_, dy_ = 0.0, 0.0
                else:
                    speed = max_speed  # min(max_speed, √(2 a d), d / dt), Python's min
                    brake = math.sqrt(2.0 * max_accel * dist)
                    if brake < speed:
                        speed = brake
                    if dist / dt < speed:
                        speed = dist / dt
                    dx_, dy_ = dx / dist * speed, dy / dist * speed
            v0x, v0y = vx, vy
            ax, ay = dx_ - vx, dy_ - vy
            dv = py_hypot(ax, ay)
            if dv > dv_max:
                ax, ay = ax * dv_max / dv, ay * dv_max / dv
            vx, vy = vx + ax, vy + ay
            speed = py_hypot(vx, vy)
            if speed > max_speed:
                vx, vy = vx * max_speed / speed, vy * max_speed / speed
            if speed < 1e-12:
                vx = vy = 0.0
            x, y = x + vx * dt, y + vy * dt
            if goal and py_hypot(x - gx, y - gy) < _ARRIVED and py_hypot(v0x, v0y) <= dv_max:
                x, y, vx, vy = gx, gy, 0.0, 0.0
        # `_update_press(t_end)`
        if press and not pressed and goal and x == gx and y == gy and vx == 0.0 and vy == 0.0:
            if not has_started:
                started, has_started = t_end, True
            if t_end - started >= hold_s - 1e-12:
                pressed = True
    s[A_X], s[A_Y], s[A_VX], s[A_VY] = x, y, vx, vy
    s[A_PRESSED], s[A_STARTED], s[A_HAS_STARTED] = pressed, started, has_started


ArmSteps = Callable[[float, float, int, Any, float, float, float], None]


def arm_kernel() -> ArmSteps:
    """`arm_steps` compiled (once per process)."""
    return cast(ArmSteps, _kernel(arm_steps, py_hypot=py_hypot))


# -- the camera's view of the hand -------------------------------------------------------------


def camera_landmarks(hand: Any, x: float, y: float, z: Any, common: float, each: float,
                     out: Any) -> None:
    """The noisy landmarks `Participant.landmarks` makes, written into out (n × 2).

    `z`: the frame's 2 + 2n standard normals (the common shift's x and y, then each landmark's),
    as `landmarks` draws them. Its NumPy expression element by element, operation for
    operation: (template + centre) + (0 + common × z) + (0 + each × z), then clipped to the
    image as `clip` does it (the larger of the value and 0, unless it is not larger: +0.0;
    then the smaller of that and 1). Only ever compiled: as Python, the NumPy expression is
    quicker and is the reference tests/unit/test_loop_speed.py holds this to.
    """
    cx = 0.0 + common * z[0]
    cy = 0.0 + common * z[1]
    for i in range(hand.shape[0]):
        vx = hand[i, 0] + x + cx + (0.0 + each * z[2 + 2 * i])
        vy = hand[i, 1] + y + cy + (0.0 + each * z[3 + 2 * i])
        vx = vx if vx > 0.0 else 0.0
        vy = vy if vy > 0.0 else 0.0
        out[i, 0] = vx if vx < 1.0 else 1.0
        out[i, 1] = vy if vy < 1.0 else 1.0


Camera = Callable[[Any, float, float, Any, float, float, Any], None]


def column_sum(pts: Any, k: int) -> float:
    """NumPy's `add.reduce(pts[:, k])` for 8 to 128 rows: its pairwise summation, in its order.

    Eight running sums over the rows in blocks of eight, added as ((0+1)+(2+3))+((4+5)+(6+7)),
    then the rows past the last whole block one by one (NumPy's `pairwise_sum` below its block
    size of 128; fewer than 8 rows it sums otherwise, so `pose_view` is not used there).
    """
    n = pts.shape[0]
    r0, r1, r2, r3 = pts[0, k], pts[1, k], pts[2, k], pts[3, k]
    r4, r5, r6, r7 = pts[4, k], pts[5, k], pts[6, k], pts[7, k]
    i = 8
    whole = n - n % 8
    while i < whole:
        r0 += pts[i, k]
        r1 += pts[i + 1, k]
        r2 += pts[i + 2, k]
        r3 += pts[i + 3, k]
        r4 += pts[i + 4, k]
        r5 += pts[i + 5, k]
        r6 += pts[i + 6, k]
        r7 += pts[i + 7, k]
        i += 8
    total = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        total += pts[i, k]
        i += 1
    return total


VIEW_ROWS = (8, 128)  # the landmark counts `pose_view` sums as NumPy does


def pose_view(pts: Any, bounds: Any) -> tuple[float, float, bool]:
    """(centre x, centre y, reach) of landmarks: the offline loop's `centre` and its box pre-test.

    The centre is `closed_loop.centre`'s (NumPy's mean: `column_sum` / n); reach, whether the
    landmarks' bounding box meets any box (rows of `bounds`: x1, x2, y1, y2), as the frame tests
    it. One compiled call where Python made five; held to `closed_loop.view_of` bit for bit.
    """
    n = pts.shape[0]
    x_lo = x_hi = pts[0, 0]
    y_lo = y_hi = pts[0, 1]
    for i in range(1, n):
        x, y = pts[i, 0], pts[i, 1]
        if x < x_lo:
            x_lo = x
        if x > x_hi:
            x_hi = x
        if y < y_lo:
            y_lo = y
        if y > y_hi:
            y_hi = y
    reach = False
    for b in range(bounds.shape[0]):
        if (x_lo <= bounds[b, 1] and bounds[b, 0] <= x_hi and y_lo <= bounds[b, 3]
                and bounds[b, 2] <= y_hi):
            reach = True
            break
    return column_sum(pts, 0) / n, column_sum(pts, 1) / n, reach


PoseView = Callable[[Any, Any], tuple[float, float, bool]]


def view_kernel() -> PoseView:
    """`pose_view` compiled (once per process)."""
    return cast(PoseView, _kernel(pose_view, column_sum=column_sum))


def camera_kernel() -> Camera:
    """`camera_landmarks` compiled (once per process)."""
    return cast(Camera, _kernel(camera_landmarks))


def hypot_kernel() -> Callable[[float, float], float]:
    """`py_hypot` compiled, as the compiled steps call it (once per process; for the tests)."""
    return cast(Callable[[float, float], float], _kernel(py_hypot))
