"""The pure model: every equation and state machine of the paper, in one place, with no I/O.

Where each piece lives (services call these; the tests test these):

    dynamics.py     eqs 1-2 (`opinion_rate`), RK4, the Jacobian (eq 3), thresholds u*, u_d*
    observer.py     eq 7 and Algorithm 1's direction reading: ẑ_h from hand motion
    bias.py         eq 6: the robot's bias controller and its freeze (Algorithm 1)
    decision.py     the decision engine: observer → eq 1 + eq 6 with a zero-order hold
    debounce.py     the one debounce (C_max) of Algorithm 2 and the switch count, any N
    behaviour.py    Algorithm 2: the robot's moves and press, over any number of boxes
    arm.py          the arm interface and the kinematic simulated arm
    device.py       connect / disconnect, and a `with` block that leaves a device safe
    checks.py       the parameter dataclasses' checks (finite, > 0, >= 0), worded once
    outcome.py      C / CH / D / DH, switches, rule violations; `judge_trial`
    scoring.py      the participant's score (Sec 3.2)
    protocol.py     the 8-trial schedule and `SessionProtocol`, the session state machine
    gaze.py         gaze levels (Sec 5) and the attention gesture
    servos.py       gaze → servo angles and pulses, with limits
    safety.py       the watchdog: stale inputs, lost liveliness, e-stop → safe stop
    geometry.py     table layout, boxes, commit line, the hand template
    participant.py  the simulated participant (eq 2 driving a hand)
    params.py       NodConfig: every SPEC default in one typed tree
    options*.py     more than two options (docs/multi-option.md): N_o-option dynamics and
                    thresholds, the N_o-box table and observer, eq 6 toward O among N_o
                    options

Nothing here imports zenoh, OpenCV, serial, Rerun, SQLite, msgpack, threads or clocks: time is
passed in (import-linter holds this; see pyproject.toml).
"""
